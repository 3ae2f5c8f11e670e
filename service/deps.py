"""Dependencies of the routes, as ``Annotated`` aliases: the settings, the job manager, the API key check."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, Request, Security
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer

from .errors import ApiError
from .jobs import JobManager
from .settings import Settings

_api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False, description="The server's COLONLIGHT_API_KEY.")
_bearer = HTTPBearer(auto_error=False, description="`Authorization: Bearer <COLONLIGHT_API_KEY>`.")


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def get_manager(request: Request) -> JobManager:
    manager: JobManager = request.app.state.manager
    return manager


SettingsDep = Annotated[Settings, Depends(get_settings)]
ManagerDep = Annotated[JobManager, Depends(get_manager)]


def key_is_valid(settings: Settings, *offered: str | None) -> bool:
    """True when the server has no key, or one of ``offered`` is it (compared in constant time).

    The one key check of the service: the HTTP routes (through :func:`require_api_key`) and the WebSocket route
    (headers, or its start message for browsers, which cannot set headers on a WebSocket) both use it.
    """
    if settings.api_key is None:
        return True
    expected = settings.api_key.get_secret_value().encode()
    return any(key is not None and secrets.compare_digest(key.encode(), expected) for key in offered)


def require_api_key(
    settings: SettingsDep,
    api_key: Annotated[str | None, Security(_api_key_header)] = None,
    bearer: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)] = None,
) -> None:
    """401 unless the request carries the server's key (when one is set) as X-API-Key or a Bearer token."""
    if key_is_valid(settings, api_key, bearer.credentials if bearer is not None else None):
        return
    raise ApiError(
        401,
        "unauthorized",
        "this server requires an API key: send it as an X-API-Key header or as Authorization: Bearer <key>",
        {"WWW-Authenticate": "Bearer", "Connection": "close"},
    )  # close: never read a refused upload


Authenticated = Depends(require_api_key)
