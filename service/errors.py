"""JSON errors everywhere: one body shape, exception handlers, and a guard for responses made outside them.

Every error the service sends looks like ``{"status": 415, "code": "unsupported_media_type", "message": "..."}``
(plus ``details`` for validation errors). Routes raise :class:`ApiError`; FastAPI's and Starlette's own errors
(404 for an unknown path, 405, 422 validation) are rewritten by the handlers; a bug becomes a JSON 500 and is
logged; :class:`JsonErrorGuard` turns the few plain-text errors Starlette writes itself (a malformed ``Range``
header: 400/416) into the same shape.
"""

from __future__ import annotations

import errno
import json
import logging
import sqlite3
from collections.abc import Mapping
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger("colonlight.service")


class ErrorDetail(BaseModel):
    loc: list[str | int] = Field(default_factory=list, description="Where the problem is, e.g. ['body', 'fps'].")
    msg: str
    type: str


class ErrorBody(BaseModel):
    """The body of every error response."""

    status: int = Field(description="The HTTP status code, repeated.")
    code: str = Field(description="A stable machine-readable code, e.g. `payload_too_large`.")
    message: str = Field(description="What went wrong, in one sentence for a person.")
    details: list[ErrorDetail] | None = Field(None, description="Per-field problems of a 422.")

    model_config = {
        "json_schema_extra": {
            "examples": [
                {
                    "status": 415,
                    "code": "unsupported_media_type",
                    "message": "clip.mp4 is not a video: the content is not a recognised video format",
                }
            ]
        }
    }


class ApiError(Exception):
    """An expected error, sent as JSON with ``status``."""

    def __init__(self, status: int, code: str, message: str, headers: Mapping[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.headers = dict(headers or {})


_DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})


def is_disk_full(exc: BaseException | None) -> bool:
    """True for "no space left" in any of its forms: an OSError (ENOSPC, EDQUOT, EFBIG) or SQLite's SQLITE_FULL,
    raised as such or as the cause of another error (the engine wraps OS errors in its own, naming the file)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in _DISK_FULL_ERRNOS:
            return True
        if isinstance(exc, sqlite3.Error) and (
            getattr(exc, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL or "disk is full" in str(exc)
        ):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def storage_full() -> ApiError:
    """507 for a request that needed space in the data folder and found none (nothing of it is kept)."""
    return ApiError(
        507,
        "insufficient_storage",
        "the server's data folder is full; nothing of this request was kept, retry later",
        {"Retry-After": "60", "Connection": "close"},
    )


def _code_for(status: int) -> str:
    try:
        return HTTPStatus(status).phrase.lower().replace(" ", "_").replace("-", "_")
    except ValueError:
        return "error"


def error_response(
    status: int,
    code: str,
    message: str,
    headers: Mapping[str, str] | None = None,
    details: list[dict[str, Any]] | None = None,
) -> JSONResponse:
    body: dict[str, Any] = {"status": status, "code": code, "message": message}
    if details is not None:
        body["details"] = details
    return JSONResponse(body, status_code=status, headers=dict(headers or {}))


def _safe_text(value: Any, limit: int = 300) -> str:
    text = value if isinstance(value, str) else repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _validation_details(exc: RequestValidationError) -> list[dict[str, Any]]:
    details = []
    for err in exc.errors():
        loc = [p if isinstance(p, int) else _safe_text(p, 100) for p in err.get("loc", ())]
        details.append(
            {"loc": loc, "msg": _safe_text(err.get("msg", "invalid value")), "type": str(err.get("type", ""))}
        )
    return details


def install_error_handlers(app: FastAPI) -> None:
    """JSON bodies for ApiError, HTTPException, validation errors and anything unexpected."""

    @app.exception_handler(ApiError)
    async def _api_error(_: Request, exc: ApiError) -> JSONResponse:
        return error_response(exc.status, exc.code, exc.message, exc.headers)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        status = exc.status_code
        if status == 404:
            message = "no such route" if exc.detail in (None, "Not Found") else str(exc.detail)
        elif status == 405:
            message = "method not allowed on this route"
        else:
            message = str(exc.detail) if exc.detail else HTTPStatus(status).phrase
        return error_response(status, _code_for(status), message, getattr(exc, "headers", None))

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_: Request, exc: RequestValidationError) -> JSONResponse:
        details = _validation_details(exc)
        first = details[0] if details else None
        where = ".".join(str(p) for p in first["loc"] if p not in ("body", "query", "path", "header")) if first else ""
        message = f"invalid request: {where + ': ' if where else ''}{first['msg']}" if first else "invalid request"
        return error_response(422, "validation_error", message, details=details)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        if is_disk_full(exc):  # wherever it struck (a result zip, the job table): 507, never a 500
            log.error("%s %s: the data folder is full (%s)", request.method, request.url.path, exc)
            full = storage_full()
            return error_response(full.status, full.code, full.message, full.headers)
        log.exception("unexpected error on %s %s", request.method, request.url.path)
        return error_response(500, "internal_error", f"internal error ({type(exc).__name__}); see the server log")


class JsonErrorGuard:
    """ASGI middleware: an error response (>= 400) that is not JSON is replaced by the JSON error shape.

    Covers the responses Starlette writes itself, outside the exception handlers (``FileResponse``'s 400/416 for
    a bad ``Range``). Successful responses and JSON errors pass through untouched and unbuffered.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start: Message | None = None
        body = bytearray()
        rewriting = False

        async def guarded_send(message: Message) -> None:
            nonlocal start, rewriting
            if message["type"] == "http.response.start":
                headers = {k.lower(): v for k, v in message.get("headers", [])}
                ctype = headers.get(b"content-type", b"")
                if message["status"] >= 400 and not ctype.startswith(b"application/json"):
                    rewriting, start = True, message
                    return
                await send(message)
                return
            if message["type"] == "http.response.body" and rewriting:
                body.extend(message.get("body", b""))
                if message.get("more_body", False):
                    return
                assert start is not None
                status = start["status"]
                text = body.decode("utf-8", "replace").strip() or HTTPStatus(status).phrase
                payload = json.dumps(
                    {"status": status, "code": _code_for(status), "message": _safe_text(text)}
                ).encode()
                keep = [
                    (k, v) for k, v in start.get("headers", []) if k.lower() not in (b"content-type", b"content-length")
                ]
                await send(
                    {
                        **start,
                        "headers": keep
                        + [(b"content-type", b"application/json"), (b"content-length", str(len(payload)).encode())],
                    }
                )
                await send({"type": "http.response.body", "body": payload})
                return
            await send(message)

        await self.app(scope, receive, guarded_send)


def error_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` entries documenting the JSON error body for ``statuses``."""
    return {s: {"model": ErrorBody, "description": HTTPStatus(s).phrase} for s in statuses}
