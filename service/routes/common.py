"""Helpers shared by the upload routes: form options, the job view."""

from __future__ import annotations

from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from ..jobs import JobManager
from ..schemas import JobLinks, JobOptions, JobStatus, iso
from ..store import JobRecord


def parse_options(fields: dict[str, str]) -> JobOptions:
    """The form fields beside the file, validated like a JSON body would be (422 on error)."""
    try:
        return JobOptions.model_validate(fields)
    except ValidationError as exc:
        raise RequestValidationError(
            [{"loc": ("body", *err["loc"]), "msg": err["msg"], "type": err["type"]} for err in exc.errors()]
        ) from None


def job_view(rec: JobRecord, manager: JobManager) -> JobStatus:
    base = f"/v1/jobs/{rec.id}"
    total = rec.frames_total
    progress = None
    if rec.status == "succeeded":
        progress = 1.0
    elif total:
        progress = round(min(1.0, rec.frames_done / total), 4)
    return JobStatus(
        id=rec.id, status=rec.status, filename=rec.filename, options=rec.options,  # type: ignore[arg-type]
        frames_done=rec.frames_done, frames_total=total, progress=progress, error=rec.error, note=rec.note,
        attempts=rec.attempts, created_at=iso(rec.created_at), started_at=iso(rec.started_at),  # type: ignore[arg-type]
        finished_at=iso(rec.finished_at),
        expires_at=iso(rec.finished_at + manager.settings.result_ttl_seconds) if rec.finished_at is not None else None,
        links=JobLinks(self=base, video=f"{base}/video", gammas=f"{base}/gammas", frames=f"{base}/frames.zip"),
    )
