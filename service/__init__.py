"""colonlight's HTTP service (installed as ``colonlight_service``): ``create_app(settings)`` and its settings."""

from __future__ import annotations

from .app import create_app
from .settings import Settings

__all__ = ["Settings", "create_app"]
