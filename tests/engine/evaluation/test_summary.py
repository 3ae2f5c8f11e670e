"""The per-method summary on constructed records with known answers: PSNR compared over the same clips, and no
gap-closed ratio of two tiny differences."""

from __future__ import annotations

import math
from typing import Any

import pytest

from colonlight.evaluation.records import ClipRecord, EvaluationResult, MethodClipResult
from colonlight.evaluation.summary import MIN_GAP, summarize


def _clip(name: str, results: dict[str, MethodClipResult]) -> ClipRecord:
    return ClipRecord(name, {}, "depth+pose", 1.0, [], [], results=results)


def _result(clips: list[ClipRecord], labels: list[str]) -> EvaluationResult:
    methods = [{"label": lab, "name": lab} for lab in labels]
    return EvaluationResult(methods=methods, clips=clips, settings={"brightness": ["fixed"]})


def _tracked(fraction: float) -> dict[str, dict[str, Any]]:
    return {"fixed": {"applicable": True, "success": fraction == 1.0, "tracked_fraction": fraction}}


def test_psnr_of_input_and_output_is_over_the_same_clips() -> None:
    """A steady clip (input == clean: infinite input PSNR) that a method changes slightly used to be averaged
    into the method's PSNR but not the input's: 20 -> 30 dB here for a method that restores nothing."""
    disturbed = MethodClipResult("a", "m", psnr_in=20.0, psnr_out=20.0)
    steady = MethodClipResult("b", "m", psnr_in=math.inf, psnr_out=40.0)
    (row,) = summarize(_result([_clip("a", {"m": disturbed}), _clip("b", {"m": steady})], ["m"]))
    assert row["psnr_in"] == 20.0 and row["psnr_out"] == 20.0
    (row,) = summarize(_result([_clip("b", {"m": steady})], ["m"]))  # steady clips only: nothing to restore
    assert math.isnan(row["psnr_in"]) and math.isnan(row["psnr_out"])


@pytest.mark.parametrize(("oracle", "closed"), [(0.9 + MIN_GAP / 2, None), (0.9 + MIN_GAP, 0.5), (1.0, 0.05)])
def test_gap_closed_needs_an_oracle_lead_of_at_least_min_gap(oracle: float, closed: float | None) -> None:
    method = 0.9 + 0.005
    labels = ["oracle-curve", "none", "m"]
    fractions = {"oracle-curve": oracle, "none": 0.9, "m": method}
    results = {lab: MethodClipResult("a", lab, tracking=_tracked(fractions[lab])) for lab in labels}
    rows = {r["method"]: r for r in summarize(_result([_clip("a", results)], labels))}
    got = rows["m"]["gap_closed_tracked_fixed"]
    assert got is None if closed is None else got == pytest.approx(closed)
