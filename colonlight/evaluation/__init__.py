"""Downstream evaluation of lighting correction: how well enhanced clips can be tracked."""

from __future__ import annotations

from .tracker import BRIGHTNESS_MODES, TrackerSettings, TrackResult, track_clip

__all__ = ["BRIGHTNESS_MODES", "TrackResult", "TrackerSettings", "track_clip"]
