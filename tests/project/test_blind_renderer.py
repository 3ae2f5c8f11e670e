"""`python -m benchmarks blind_renderer` renders clips the evaluator takes as synthetic clips with ground truth,
the same bytes for the same seed, with depth and poses that agree with the frames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmarks.blind_renderer import render_clips
from colonlight.evaluation import EvalMethod, evaluate_clips, find_clips


def test_clips_are_found_tracked_and_reproducible(tmp_path: Path) -> None:
    folders = render_clips(tmp_path / "a", seed=0, clips=4, frames=4, width=96, height=80, workers=1)
    again = render_clips(tmp_path / "b", seed=0, clips=1, frames=4, width=96, height=80, workers=1)
    assert all((a / "frames" / "000003.png").read_bytes() == (b / "frames" / "000003.png").read_bytes()
               for a, b in zip(folders, again, strict=False))  # fmt: skip
    assert json.loads((folders[3] / "lighting.json").read_text())["steady"]  # every 4th clip is steady
    refs = find_clips([tmp_path / "a"])
    assert len(refs) == 4
    result = evaluate_clips(refs[:1], [EvalMethod.of("none", "none")], colmap=False, brightness=("fixed",))
    (clip,) = result.clips
    clean = clip.results["clean"].tracking or {}
    # the clean frames of a slow clip track every frame: depth, poses and intrinsics agree with the pictures
    assert clean["fixed"]["applicable"] and clean["fixed"]["tracked_fraction"] == 1.0
    assert np.isfinite(clip.results["none"].psnr_in or np.nan)  # a disturbed clip
