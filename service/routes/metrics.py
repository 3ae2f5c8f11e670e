"""``/metrics`` in the Prometheus text format, and ``/v1/info`` (what this server offers)."""

from __future__ import annotations

import anyio
from fastapi import APIRouter
from fastapi.responses import PlainTextResponse

from colonlight import __version__
from colonlight.limits import DEFAULT_FRAME_FORMAT, DEFAULT_JPEG_QUALITY, MAX_FPS

from ..deps import Authenticated, ManagerDep
from ..errors import error_responses
from ..metrics import CONTENT_TYPE
from ..schemas import METHODS, ServiceInfo
from ..uploads import MAX_MASK_BYTES

router = APIRouter(dependencies=[Authenticated])


@router.get(
    "/metrics",
    tags=["metrics"],
    summary="Prometheus metrics: jobs by status, frames processed, processing seconds, queue depth",
    response_class=PlainTextResponse,
    responses={
        200: {
            "content": {"text/plain": {"example": "# TYPE colonlight_queue_depth gauge\ncolonlight_queue_depth 0.0\n"}},
            "description": "Prometheus text exposition format 0.0.4.",
        },
        **error_responses(401),
    },
)
async def metrics(manager: ManagerDep) -> PlainTextResponse:
    assert manager.store is not None
    counts = await anyio.to_thread.run_sync(manager.store.counts)
    waiting, running, admitted = manager.queue_state()
    s = manager.settings
    text = manager.metrics.render(counts, waiting, running, s.workers, admitted, s.capacity, manager.readiness()[0])
    return PlainTextResponse(text, media_type=CONTENT_TYPE)


@router.get(
    "/v1/info",
    tags=["info"],
    summary="Version, methods, defaults and limits of this server",
    response_model=ServiceInfo,
    responses=error_responses(401),
)
async def info(manager: ManagerDep) -> ServiceInfo:
    s = manager.settings
    return ServiceInfo(
        version=__version__,
        methods=METHODS,
        defaults={
            "method": s.method,
            "fps": s.fps,
            "model_size": s.model_size,
            "format": DEFAULT_FRAME_FORMAT,
            "quality": DEFAULT_JPEG_QUALITY,
            "frames": True,
            "model": manager.model_info,
        },
        limits={
            "max_upload_mb": s.max_upload_mb,
            "max_content_mask_bytes": MAX_MASK_BYTES,  # the `content_mask` part's own cap, beside the clip's
            "max_pixels": s.max_pixels,  # a clip's frames and a mask alike (COLONLIGHT_MAX_PIXELS)
            "max_fps": MAX_FPS,
            "sync_max_seconds": s.sync_max_seconds,
            "result_ttl_seconds": s.result_ttl_seconds,
            "workers": s.workers,
            "torch_threads": manager.torch_threads,
            "queue_size": s.queue_size,
            "stream_max": s.stream_max,
            "stream_max_frame_mb": s.stream_max_frame_mb,
        },
        auth_required=s.api_key is not None,
    )
