"""`python -m benchmarks motion_cue` measures what it says on cases with known answers: a pure gain change is
tracked brightening with no area change, a zoom is area change with no brightening."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from benchmarks.motion_cue import SIDE, grey, pair_cue


def texture(side: int, seed: int = 3) -> np.ndarray:
    """A smooth random mid-grey RGB texture (enough structure for optical flow)."""
    noise = np.random.default_rng(seed).random((side // 8, side // 8)).astype(np.float32)
    smooth = cv2.resize(noise, (side, side), interpolation=cv2.INTER_CUBIC)
    level = np.clip(60 + 120 * smooth, 0, 255).astype(np.uint8)
    return np.repeat(level[..., None], 3, axis=2)


@pytest.fixture
def flow() -> cv2.DISOpticalFlow:
    return cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)


def test_a_gain_change_is_brightening_without_area_change(flow: cv2.DISOpticalFlow) -> None:
    before = texture(4 * SIDE)
    after = np.clip(before.astype(np.float32) * 1.3, 0, 255).astype(np.uint8)
    obs, div = pair_cue(grey(before), grey(after), flow) or (np.nan, np.nan)
    assert obs == pytest.approx(np.log(1.3), abs=0.02)
    assert div == pytest.approx(0.0, abs=0.02)


def test_a_zoom_is_area_change_without_brightening(flow: cv2.DISOpticalFlow) -> None:
    big = texture(4 * SIDE)
    side = big.shape[0]
    crop = int(round(side / 1.1))
    start = (side - crop) // 2
    zoomed = cv2.resize(big[start : start + crop, start : start + crop], (side, side), interpolation=cv2.INTER_AREA)
    obs, div = pair_cue(grey(big), grey(zoomed), flow) or (np.nan, np.nan)
    assert div == pytest.approx(2 * np.log(side / crop), abs=0.04)  # each side grew by side / crop
    assert obs == pytest.approx(0.0, abs=0.02)
