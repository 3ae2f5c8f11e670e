"""Downstream evaluation of lighting correction: how well enhanced clips can be tracked."""

from __future__ import annotations

from .tracker import TrackerSettings, TrackResult, track_clip

__all__ = ["TrackResult", "TrackerSettings", "track_clip"]
