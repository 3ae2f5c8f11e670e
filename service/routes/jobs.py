"""``/v1/jobs``: submit a clip (202 + Location), poll it, download its results, delete it."""

from __future__ import annotations

from pathlib import Path as FsPath
from typing import Annotated

import anyio
from fastapi import APIRouter, Path, Request, Response
from fastapi.responses import FileResponse

from colonlight.limits import DEFAULT_FPS

from ..deps import Authenticated, ManagerDep, SettingsDep
from ..errors import ApiError, error_responses, is_disk_full, storage_full
from ..jobs import JOB_ID_PATTERN, JobManager
from ..request_options import upload_request_body
from ..schemas import JobStatus
from ..store import JobRecord
from .common import checked_upload, job_view

router = APIRouter(prefix="/v1", tags=["jobs"], dependencies=[Authenticated])

JobId = Annotated[
    str,
    Path(pattern=JOB_ID_PATTERN, description="The id returned by POST /v1/jobs.", examples=["q0Xq3b9bYJgP4yL2m9Vb0w"]),
]


def _job(manager: JobManager, job_id: str) -> JobRecord:
    rec = manager.get(job_id)
    if rec is None:
        raise ApiError(404, "job_not_found", f"no job {job_id} (never existed, deleted, or expired)")
    return rec


def _finished(rec: JobRecord) -> None:
    if rec.status == "failed":
        raise ApiError(409, "job_failed", f"job {rec.id} failed, it has no results: {rec.error}")
    if rec.status != "succeeded":
        raise ApiError(
            409,
            "job_not_finished",
            f"job {rec.id} is {rec.status} ({rec.frames_done} frames done); poll GET /v1/jobs/{rec.id}",
        )


@router.post(
    "/jobs",
    status_code=202,
    summary="Submit a clip for enhancement",
    description=(
        "Upload a clip as multipart/form-data (`file`, plus the options of `colonlight enhance`, and optionally a "
        "`content_mask` image used as `--content MASK` is: a bad one is a 422 naming it). The upload is "
        "streamed to disk; one over COLONLIGHT_MAX_UPLOAD_MB is refused with 413 as soon as the limit is crossed, "
        "one whose body stops arriving for COLONLIGHT_UPLOAD_IDLE_SECONDS with 408, one that finds the data folder "
        "full with 507, frames over COLONLIGHT_MAX_PIXELS (read from the stream header) with 413, content that "
        "does not decode as video with 415. The job is admitted only once its upload is complete. On success: 202 "
        "with the job and a `Location` header to poll. When the workers are busy and the queue is full, or "
        "COLONLIGHT_MAX_UPLOADS uploads are in flight: 503 with `Retry-After`."
    ),
    response_model=JobStatus,
    openapi_extra={"requestBody": upload_request_body("The clip and the enhancement options.")},
    responses={
        202: {
            "description": "Accepted: the job is queued.",
            "headers": {"Location": {"description": "URL of the job's status.", "schema": {"type": "string"}}},
        },
        **error_responses(400, 401, 408, 413, 415, 422, 503, 507),
    },
)
async def submit_job(request: Request, response: Response, manager: ManagerDep, settings: SettingsDep) -> JobStatus:
    async with checked_upload(request, manager, settings) as c:
        rec = await manager.create_job(c.admission, c.upload, c.options)
    response.headers["Location"] = f"/v1/jobs/{rec.id}"
    return job_view(rec, manager)


@router.get(
    "/jobs/{job_id}",
    summary="Status and progress of a job",
    response_model=JobStatus,
    responses=error_responses(401, 404, 422),
)
def get_job(job_id: JobId, manager: ManagerDep) -> JobStatus:
    return job_view(_job(manager, job_id), manager)


def _file(path: FsPath, media_type: str, filename: str | None = None) -> FileResponse:
    if not path.is_file():
        raise ApiError(404, "result_missing", "the result file is missing on the server")
    return FileResponse(path, media_type=media_type, filename=filename, content_disposition_type="inline")


@router.get(
    "/jobs/{job_id}/video",
    summary="The enhanced video (H.264 mp4; range requests supported)",
    response_class=FileResponse,
    responses={
        200: {
            "content": {"video/mp4": {"schema": {"type": "string", "format": "binary"}}},
            "description": "The enhanced clip; send `Range: bytes=a-b` for a part (206).",
        },
        **error_responses(401, 404, 409, 422),
    },
)
def get_video(job_id: JobId, manager: ManagerDep) -> FileResponse:
    rec = _job(manager, job_id)
    _finished(rec)
    return _file(manager.result_path(rec, "video"), "video/mp4", f"{FsPath(rec.filename).stem}-enhanced.mp4")


@router.get(
    "/jobs/{job_id}/gammas",
    summary="The clip's gammas.json (exactly what `colonlight enhance` writes)",
    response_class=FileResponse,
    responses={
        200: {
            "content": {
                "application/json": {
                    "schema": {"type": "object"},
                    "example": {
                        "clip": "p7",
                        "fps": DEFAULT_FPS,
                        "method": "rnn",
                        "frame_count": 36,
                        "frames": [{"index": 0, "time_s": 0.0, "source_time_s": 0.0, "gamma": 1.0, "seed": True}],
                    },
                }
            },
            "description": "Per-frame gammas and the settings that made them.",
        },
        **error_responses(401, 404, 409, 422),
    },
)
def get_gammas(job_id: JobId, manager: ManagerDep) -> FileResponse:
    rec = _job(manager, job_id)
    _finished(rec)
    return _file(manager.result_path(rec, "gammas"), "application/json")


@router.get(
    "/jobs/{job_id}/frames.zip",
    summary="The enhanced frames as a zip (frames/000000.png ...)",
    response_class=FileResponse,
    responses={
        200: {
            "content": {"application/zip": {"schema": {"type": "string", "format": "binary"}}},
            "description": "The frames, stored uncompressed.",
        },
        **error_responses(401, 404, 409, 422, 507),
    },
)
async def get_frames_zip(job_id: JobId, manager: ManagerDep) -> FileResponse:
    rec = await anyio.to_thread.run_sync(_job, manager, job_id)
    _finished(rec)
    if not rec.options.get("frames", True):
        raise ApiError(404, "no_frames", f"job {rec.id} was run with frames=false: only the video and gammas exist")
    try:
        path = await anyio.to_thread.run_sync(manager.frames_zip, rec)
    except OSError as exc:
        if is_disk_full(exc):  # no room to build the zip: nothing half-written is left (atomic)
            raise storage_full() from None
        raise ApiError(404, "result_missing", f"the frames of job {rec.id} are missing on the server") from None
    return FileResponse(path, media_type="application/zip", filename=f"{FsPath(rec.filename).stem}-frames.zip")


@router.delete(
    "/jobs/{job_id}",
    status_code=204,
    summary="Delete a job and its files (stops it if running)",
    responses={204: {"description": "Deleted."}, **error_responses(401, 404, 422)},
)
def delete_job(job_id: JobId, manager: ManagerDep) -> Response:
    if not manager.delete(job_id):
        raise ApiError(404, "job_not_found", f"no job {job_id} (never existed, deleted, or expired)")
    return Response(status_code=204)
