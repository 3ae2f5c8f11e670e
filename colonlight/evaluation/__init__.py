"""Downstream evaluation of lighting correction: how well enhanced clips can be tracked.

The names below are the evaluation's public API (``colonlight evaluate`` uses only these); they load on first
use, as :mod:`colonlight`'s do, so that importing the package costs nothing until a name is needed.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS: dict[str, str] = {
    "ClipRef": "clips",
    "EvalClip": "clips",
    "find_clips": "clips",
    "make_benchmark": "clips",
    "unique_clips": "clips",
    "ClipRecord": "records",
    "EvaluationResult": "records",
    "MethodClipResult": "records",
    "fmt": "report",
    "fmt_pair": "report",
    "success_cell": "report",
    "write_report": "report",
    "DEFAULT_METHODS": "runner",
    "EvalMethod": "runner",
    "evaluate_clip": "runner",
    "evaluate_clips": "runner",
    "method_list": "runner",
    "missing_extras": "requirements",
    "require_extras": "requirements",
    "failure_breakdown": "summary",
    "summarize": "summary",
    "BRIGHTNESS_MODES": "tracker",
    "TrackResult": "tracker",
    "TrackerSettings": "tracker",
    "track_clip": "tracker",
}

if TYPE_CHECKING:
    from .clips import ClipRef, EvalClip, find_clips, make_benchmark, unique_clips
    from .records import ClipRecord, EvaluationResult, MethodClipResult
    from .report import fmt, fmt_pair, success_cell, write_report
    from .requirements import missing_extras, require_extras
    from .runner import (
        DEFAULT_METHODS,
        EvalMethod,
        evaluate_clip,
        evaluate_clips,
        method_list,
    )
    from .summary import failure_breakdown, summarize
    from .tracker import BRIGHTNESS_MODES, TrackerSettings, TrackResult, track_clip


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


__all__ = [
    "BRIGHTNESS_MODES",
    "ClipRecord",
    "ClipRef",
    "DEFAULT_METHODS",
    "EvalClip",
    "EvalMethod",
    "EvaluationResult",
    "MethodClipResult",
    "TrackResult",
    "TrackerSettings",
    "evaluate_clip",
    "evaluate_clips",
    "failure_breakdown",
    "find_clips",
    "fmt",
    "fmt_pair",
    "make_benchmark",
    "method_list",
    "missing_extras",
    "require_extras",
    "success_cell",
    "summarize",
    "track_clip",
    "unique_clips",
    "write_report",
]
