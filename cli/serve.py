"""``colonlight serve``: the HTTP service (FastAPI under uvicorn); settings from ``COLONLIGHT_*`` variables."""

from __future__ import annotations

import logging
import socket

import typer

from .display import error_line


def _listening_sockets(host: str, port: int) -> list[socket.socket]:
    """The server's sockets, bound before the model loads, one per address ``host`` resolves to (as asyncio binds
    them for uvicorn: IPv6 ones IPv6-only). An address in use or a host that does not resolve is one line naming
    the address: uvicorn bound after the app had started, logged the cause without the address, and the process
    then aborted in a C++ destructor ("terminate called without an active exception")."""
    where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    sockets: list[socket.socket] = []
    try:
        kinds = {"type": socket.SOCK_STREAM, "proto": socket.IPPROTO_TCP, "flags": socket.AI_PASSIVE}
        infos = socket.getaddrinfo(host, port, **kinds)
        for family, kind, proto, _, address in dict.fromkeys(infos):
            sock = socket.socket(family, kind, proto)
            sockets.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a restart reuses the port at once
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
    except (OSError, UnicodeError) as exc:  # socket.gaierror (an OSError): a host that does not resolve
        for sock in sockets:
            sock.close()
        error_line(f"cannot listen on {where}: {str(getattr(exc, 'strerror', None) or exc).lower()}")
        raise typer.Exit(1) from None
    return sockets


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
    sockets = _listening_sockets(settings.host, settings.port)
    bound_port = sockets[0].getsockname()[1]  # the port a --port 0 was given
    url = f"http://[{settings.host}]:{bound_port}" if ":" in settings.host else f"http://{settings.host}:{bound_port}"

    class _AnnouncingServer(uvicorn.Server):
        """uvicorn's server, saying where it listens once it does (it says so only for a socket it bound itself)."""

        async def startup(self, sockets: list[socket.socket] | None = None) -> None:
            await super().startup(sockets)
            if self.started:
                logging.getLogger("uvicorn.error").info("Uvicorn running on %s (Press CTRL+C to quit)", url)

    config = uvicorn.Config(
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
    server = _AnnouncingServer(config)
    try:
        server.run(sockets=sockets)  # uvicorn.run's one-process path, on the sockets bound above
    except KeyboardInterrupt:
        pass
    finally:
        for sock in sockets:
            sock.close()
    if not server.started:
        raise typer.Exit(3)  # uvicorn's STARTUP_FAILURE: the app's startup failed (it logged why)


def register(app: typer.Typer) -> None:
    app.command("serve")(serve)
