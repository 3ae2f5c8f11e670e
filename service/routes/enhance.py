"""``POST /v1/enhance``: a short clip in, its gammas and enhanced video out, in one response."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from ..deps import Authenticated, ManagerDep, SettingsDep
from ..errors import error_responses
from ..request_options import upload_request_body
from ..schemas import EnhanceResult
from .common import checked_upload

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
    responses=error_responses(400, 401, 408, 413, 415, 422, 503, 507),
)
async def enhance_now(request: Request, manager: ManagerDep, settings: SettingsDep) -> dict[str, Any]:
    async with checked_upload(request, manager, settings) as c:
        return await manager.enhance_now(c.admission, c.upload, c.options, c.info)
