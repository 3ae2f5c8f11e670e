"""What an evaluation records: one result per method and clip, one record per clip, and the whole run, with
their JSON form (the report's ``evaluation.json``). Running: :mod:`.runner`; the per-method summary:
:mod:`.summary`."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from .summary import failure_breakdown, summarize


@dataclass
class MethodClipResult:
    """One method on one clip. Fractions in [0, 1]; luminance in [0, 1]; time in milliseconds."""

    clip: str
    method: str
    frames: int = 0
    ms_per_frame: float = float("nan")
    cpu_ms_per_frame: float = float("nan")
    flicker_in: float = float("nan")
    flicker_out: float = float("nan")
    mean_luma_in: float = float("nan")
    mean_luma_out: float = float("nan")
    psnr_in: float | None = None
    psnr_out: float | None = None
    ssim_in: float = float("nan")
    ssim_out: float = float("nan")
    dark_in: float = float("nan")
    dark_out: float = float("nan")
    bright_in: float = float("nan")
    bright_out: float = float("nan")
    luma_out: list[float] = field(default_factory=list)
    ssim_series: list[float] = field(default_factory=list)
    gammas: list[float | None] | None = None
    tracking: dict[str, dict[str, Any]] | None = None  # brightness setting ("fixed", "affine") -> result
    colmap: dict[str, Any] | None = None
    error: str | None = None
    detail: str | None = None  # traceback of an unexpected error

    @property
    def flicker_reduction(self) -> float:
        return 1.0 - self.flicker_out / self.flicker_in if self.flicker_in > 0 else float("nan")


@dataclass
class ClipRecord:
    """A clip's description, its input series and one result per method."""

    name: str
    info: dict[str, Any]
    correspondence: str  # "depth+pose" | "optical flow"
    valid_fraction: float  # mean fraction of pixels with a correspondence
    luma_in: list[float]
    ssim_in_series: list[float]
    results: dict[str, MethodClipResult] = field(default_factory=dict)
    # frames the input fails and the clean frames pass (see colonlight.evaluation.breakdown)
    input_failures: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class EvaluationResult:
    """Everything an evaluation found; :func:`summarize` turns it into one row per method."""

    methods: list[dict[str, Any]] = field(default_factory=list)  # label, name, options, parameters, model
    skipped_methods: dict[str, str] = field(default_factory=dict)  # label -> reason
    clips: list[ClipRecord] = field(default_factory=list)
    failures: list[dict[str, str]] = field(default_factory=list)  # clip, source, error
    settings: dict[str, Any] = field(default_factory=dict)
    # clip -> label ("input" too) -> thumbnails of the strip frames
    strips: dict[str, dict[str, list[np.ndarray]]] = field(default_factory=dict)
    strip_frames: dict[str, list[int]] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def labels(self) -> list[str]:
        return [m["label"] for m in self.methods]

    @property
    def failed(self) -> bool:
        """Some clip could not be loaded, or some method failed on a clip."""
        return bool(self.failures) or any(r.error for c in self.clips for r in c.results.values())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (thumbnails left out)."""
        return {
            "methods": self.methods,
            "skipped_methods": self.skipped_methods,
            "settings": self.settings,
            "summary": summarize(self),
            "failure_breakdown": failure_breakdown(self),
            "clips": [
                {
                    **{k: v for k, v in asdict(c).items() if k != "results"},
                    "results": {label: json_result(r) for label, r in c.results.items()},
                }
                for c in self.clips
            ],
            "failures": self.failures,
            "seconds": self.seconds,
        }


def json_result(r: MethodClipResult) -> dict[str, Any]:
    d = asdict(r)
    d.pop("detail")
    d["flicker_reduction"] = r.flicker_reduction
    return d
