"""``colonlight serve``: the HTTP service (FastAPI under uvicorn); settings from ``COLONLIGHT_*`` variables."""

from __future__ import annotations

import typer

from .display import error_line


def serve(
    host: str | None = typer.Option(None, "--host", help="Address to bind (default COLONLIGHT_HOST or 127.0.0.1)."),
    port: int | None = typer.Option(None, "--port", min=0, max=65535, help="Port (default COLONLIGHT_PORT or 8000)."),
) -> None:
    """Serve the API (/v1/jobs, /v1/enhance, /v1/stream, /healthz, /readyz, /metrics) and the web page at /
    with uvicorn.

    Other settings come from the environment: COLONLIGHT_DATA_DIR, COLONLIGHT_WORKERS, COLONLIGHT_QUEUE_SIZE,
    COLONLIGHT_MAX_UPLOAD_MB, COLONLIGHT_API_KEY, COLONLIGHT_WEIGHTS, COLONLIGHT_DEVICE, ... (see the README).
    """
    import uvicorn
    from colonlight_service.app import create_app
    from colonlight_service.http_protocol import header_deadline_protocol
    from colonlight_service.settings import Settings
    from colonlight_service.workspace import Workspace
    from pydantic import ValidationError

    overrides: dict[str, object] = {}
    if host is not None:
        overrides["host"] = host
    if port is not None:
        overrides["port"] = port
    try:
        settings = Settings(**overrides)
    except ValidationError as exc:
        for err in exc.errors():
            error_line(f"COLONLIGHT_{'_'.join(str(p) for p in err['loc']).upper()}: {err['msg']}")
        raise typer.Exit(2) from None
    try:  # made here, before uvicorn: a folder that cannot be made (under /proc, read-only) was a startup traceback
        Workspace(settings.data_dir).create()
    except OSError as exc:
        where = exc.filename or settings.data_dir  # error_line escapes
        cause = "a file is in the way of a folder" if isinstance(exc, FileExistsError) else exc.strerror or str(exc)
        error_line(f"COLONLIGHT_DATA_DIR: cannot create or write {where}: {cause}")
        raise typer.Exit(2) from None
    import copy

    from uvicorn.config import LOGGING_CONFIG

    log_config = copy.deepcopy(LOGGING_CONFIG)  # the service's own log lines go where uvicorn's go
    log_config["loggers"]["colonlight"] = {
        "handlers": ["default"],
        "level": settings.log_level.upper(),
        "propagate": False,
    }
    uvicorn.run(
        create_app(settings),
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
        log_config=log_config,
        server_header=False,
        http=header_deadline_protocol(settings.header_timeout_seconds),  # slow request headers: 408 (slowloris)
        timeout_graceful_shutdown=10,
        ws_max_size=settings.stream_max_frame_bytes,  # /v1/stream: a larger message closes with 1009
        ws_per_message_deflate=False,  # /v1/stream carries JPEG/PNG, which deflate cannot shrink: spare the CPU
    )


def register(app: typer.Typer) -> None:
    app.command("serve")(serve)
