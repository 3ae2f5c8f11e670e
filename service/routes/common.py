"""Helpers shared by the upload routes: the checked upload, form options, the job view."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

import anyio
from fastapi import Request
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from colonlight import DEFAULT_CONTENT, VideoInfo

from ..errors import ApiError
from ..jobs import Admission, JobManager
from ..request_options import JobOptions
from ..schemas import JobLinks, JobStatus, iso
from ..settings import Settings
from ..store import JobRecord
from ..uploads import MASK_FIELD, Upload, receive_upload


def parse_options(fields: dict[str, str]) -> JobOptions:
    """The form fields beside the file, validated like a JSON body would be (422 on error)."""
    try:
        return JobOptions.model_validate(fields)
    except ValidationError as exc:
        raise RequestValidationError(
            [{"loc": ("body", *err["loc"]), "msg": err["msg"], "type": err["type"]} for err in exc.errors()]
        ) from None


def check_mask_options(upload: Upload, options: JobOptions) -> None:
    """422 for a ``content_mask`` part sent with ``content`` other than the default: the mask replaces the
    detection, so ``full`` beside it asks for two things at once (refused rather than one silently winning)."""
    if upload.mask is not None and options.content != DEFAULT_CONTENT:
        raise ApiError(
            422,
            "validation_error",
            f"content mask {upload.mask.filename}: a `{MASK_FIELD}` part is used instead of content detection; "
            f"leave `content` unset (or {DEFAULT_CONTENT!r}) with it, not {options.content!r}",
        )


@dataclass(frozen=True)
class CheckedUpload:
    """An admitted upload, on disk, whose options and content have been checked."""

    admission: Admission
    upload: Upload
    options: JobOptions
    info: VideoInfo


@asynccontextmanager
async def checked_upload(request: Request, manager: JobManager, settings: Settings) -> AsyncIterator[CheckedUpload]:
    """Take an upload place (503), stream the upload to disk (413, 408, 507), validate the options (422), build
    the method, probe the content (413 over the pixel cap, 415), read the content mask if one came (422, 413), and
    only then admit the job (503). On leaving, release the admission (a no-op once a job owns it) and drop the
    upload's files if they are still there (a job moves them away)."""
    upload: Upload | None = None
    admission: Admission | None = None
    try:
        with manager.receiving():
            upload = await receive_upload(
                request,
                manager.new_upload_path(),
                settings.max_upload_bytes,
                settings.upload_idle_seconds,
                settings.upload_min_bytes_per_s,
            )
            options = parse_options(upload.fields)
            check_mask_options(upload, options)
            await manager.check_method(manager.method_spec(options))
            info = await manager.probe(upload)
            await manager.check_mask(upload)
        admission = manager.admit()
        yield CheckedUpload(admission, upload, options, info)
    except ApiError as exc:
        if exc.code == "payload_too_large":
            manager.metrics.inc("rejected", "too_large")
        elif exc.status == 408:
            manager.metrics.inc("rejected", "stalled")
        raise
    finally:
        if admission is not None:
            admission.release()
        if upload is not None and upload.on_disk():
            await anyio.to_thread.run_sync(upload.discard)


def job_view(rec: JobRecord, manager: JobManager) -> JobStatus:
    base = f"/v1/jobs/{rec.id}"
    total = rec.frames_total
    progress = None
    if rec.status == "succeeded":
        progress = 1.0
    elif total:
        progress = round(min(1.0, rec.frames_done / total), 4)
    return JobStatus(
        id=rec.id,
        status=rec.status,
        filename=rec.filename,
        options=rec.options,
        frames_done=rec.frames_done,
        frames_total=total,
        progress=progress,
        error=rec.error,
        note=rec.note,
        attempts=rec.attempts,
        created_at=iso(rec.created_at),
        started_at=iso(rec.started_at),
        finished_at=iso(rec.finished_at),
        expires_at=iso(rec.finished_at + manager.settings.result_ttl_seconds) if rec.finished_at is not None else None,
        links=JobLinks(self=base, video=f"{base}/video", gammas=f"{base}/gammas", frames=f"{base}/frames.zip"),
    )
