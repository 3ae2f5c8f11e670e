"""`colonlight.enhance_frames`: the streaming API gives one result per frame, whatever the method holds back."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("method", ["deflicker", "rnn"])
def test_enhance_frames_yields_one_result_per_frame_given(method: str) -> None:
    """The README's API: a method that holds frames back (deflicker's look-ahead) still gives every frame."""
    import numpy as np

    import colonlight

    rng = np.random.default_rng(3)
    frames = [np.full((24, 32, 3), 40 + 9 * i + rng.integers(0, 20), np.uint8) for i in range(11)]
    built = colonlight.create_method(method)
    held_back = built.stream()
    pushed = [r for f in frames for r in held_back.push(f)]
    out = list(colonlight.enhance_frames(iter(frames), built))
    assert len(out) == len(frames)
    if method == "deflicker":
        assert len(pushed) < len(frames)  # push alone drops the look-ahead's last frames: the trap this avoids
    expected = pushed + held_back.flush()
    assert all(np.array_equal(a.frame, b.frame) for a, b in zip(out, expected, strict=True))
    by_name = list(colonlight.enhance_frames(frames, method))
    assert [r.gamma for r in by_name] == [r.gamma for r in out]


def test_enhance_frames_refuses_options_for_a_built_method() -> None:
    import colonlight

    with pytest.raises(TypeError):
        next(colonlight.enhance_frames([], colonlight.create_method("deflicker"), size=3))


@pytest.mark.parametrize("method", ["rnn", "deflicker", "he", "zerodce"])
def test_enhance_frames_refuses_a_bad_frame_naming_it(method: str) -> None:
    """An empty frame (a side of 0) passed the methods' type check and failed deep in OpenCV, torch or a
    division by zero, each in its own words; every bad frame is now a FrameShapeError (a ValueError) naming it."""
    import numpy as np

    import colonlight
    from colonlight.errors import FrameShapeError

    good = np.full((24, 32, 3), 90, np.uint8)
    for bad, words in (
        (np.zeros((24, 0, 3), np.uint8), "empty frame of shape (24, 0, 3)"),
        (np.zeros((0, 0, 3), np.uint8), "empty frame of shape (0, 0, 3)"),
        (np.full((24, 32, 3), 0.5), "expected an (H, W, 3) uint8 RGB frame"),
    ):
        with pytest.raises(FrameShapeError, match=r"^frame 2: ") as info:
            list(colonlight.enhance_frames([good, good, bad, good], method))
        assert isinstance(info.value, ValueError) and words in str(info.value)
