"""``POST /v1/enhance``: a short clip in, its gammas and enhanced video out, in one response."""

from __future__ import annotations

from typing import Any

import anyio
from fastapi import APIRouter, Request

from ..deps import Authenticated, ManagerDep, SettingsDep
from ..errors import ApiError, error_responses
from ..schemas import EnhanceResult, upload_request_body
from ..uploads import Upload, receive_upload
from .common import parse_options

router = APIRouter(prefix="/v1", tags=["enhance"], dependencies=[Authenticated])


@router.post(
    "/enhance",
    summary="Enhance a short clip and wait for the result",
    description=(
        "A convenience for short clips (up to COLONLIGHT_SYNC_MAX_SECONDS, default 20 s): the same pipeline as a "
        "job, run now, answered with the clip's gammas.json and the enhanced H.264 mp4 (base64) in one JSON "
        "body. A longer clip is refused with 413 and a message pointing to POST /v1/jobs. The `frames` option "
        "is ignored here (no frames are written). Shares the workers and the queue with the jobs."
    ),
    response_model=EnhanceResult,
    openapi_extra={"requestBody": upload_request_body("The clip (short) and the enhancement options.")},
    responses=error_responses(400, 401, 413, 415, 422, 503),
)
async def enhance_now(request: Request, manager: ManagerDep, settings: SettingsDep) -> dict[str, Any]:
    admission = manager.admit()
    upload: Upload | None = None
    try:
        upload = await receive_upload(request, manager.new_upload_path(), settings.max_upload_bytes)
        options = parse_options(upload.fields)
        spec = manager.method_spec(options)
        await manager.check_method(spec)
        info = await manager.probe(upload)
        return await manager.enhance_now(admission, upload, options, info)
    except ApiError as exc:
        if exc.status == 413:
            manager.metrics.inc("rejected", "too_large")
        raise
    finally:
        admission.release()
        if upload is not None and upload.path.exists():
            await anyio.to_thread.run_sync(upload.discard)
