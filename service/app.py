"""The FastAPI application: ``create_app(settings)`` wires settings, the job manager, routers and error handlers.

Run it with ``colonlight serve`` (uvicorn), or ``uvicorn --factory colonlight_service.app:create_app``.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from colonlight import __version__

from .deps import Authenticated
from .errors import JsonErrorGuard, install_error_handlers
from .jobs import JobManager
from .memory import limit_malloc_arenas
from .routes import enhance, health, jobs, metrics, page, stream
from .settings import Settings

DESCRIPTION = """\
Consistent lighting for colonoscopy video (the recurrent gamma model of Zhang et al., IPMI 2021), over HTTP.
The same engine and per-clip pipeline as `colonlight enhance`.

* `POST /v1/jobs` a clip (multipart, field `file`) -> 202 + `Location`; poll `GET /v1/jobs/{id}`;
  download `/video` (H.264 mp4, range requests), `/gammas` (gammas.json), `/frames.zip`; `DELETE` when done.
* `POST /v1/enhance` for short clips: gammas and video in one response.
* `/v1/stream` (WebSocket) for live video: JPEG/PNG frames in, a gamma record and the enhanced frame out for
  each, one recurrent state per connection (protocol in the README, "Live streams over a WebSocket").
* When the server has an API key, send it as `X-API-Key: <key>` or `Authorization: Bearer <key>`
  (not needed for `/healthz` and `/readyz`).
* Every error is JSON: `{"status", "code", "message"}`.
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    """The application for ``settings`` (default: read from ``COLONLIGHT_*`` environment variables)."""
    settings = settings or Settings()
    limit_malloc_arenas(settings.malloc_arena_max)
    manager = JobManager(settings)

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        await manager.start()  # the model starts loading now, not on the first request
        try:
            yield
        finally:
            await manager.stop()

    app = FastAPI(
        title="colonlight",
        version=__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        openapi_url=None,  # served below, behind the API key like every route but the health checks
        docs_url=None,
        redoc_url=None,
        openapi_tags=[
            {"name": "jobs", "description": "Asynchronous enhancement of clips of any length."},
            {"name": "enhance", "description": "Synchronous enhancement of short clips."},
            {"name": "health", "description": "Liveness and readiness (no API key needed)."},
            {"name": "metrics", "description": "Prometheus metrics."},
            {"name": "info", "description": "What this server offers."},
        ],
    )
    app.state.settings = settings
    app.state.manager = manager
    app.state.stream_slots = stream.StreamSlots(settings.stream_max)
    install_error_handlers(app)
    app.add_middleware(JsonErrorGuard)
    for module in (health, jobs, enhance, stream, metrics, page):
        app.include_router(module.router)
    app.mount("/static", StaticFiles(directory=page.STATIC), name="static")

    @app.get("/openapi.json", include_in_schema=False, dependencies=[Authenticated])
    async def openapi() -> dict[str, Any]:
        return app.openapi()

    return app
