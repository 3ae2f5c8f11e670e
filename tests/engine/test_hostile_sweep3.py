"""A third hostile-input sweep of the Python API (``colonlight.enhance_frames``): frames that change size part way
through a clip, whatever the content mode, and array layouts (views, negative strides, read-only, Fortran order)
that must give the bytes of their contiguous copies and leave the caller's arrays alone."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import colonlight
from colonlight import create_method
from colonlight.errors import FrameShapeError, OptionError


def _frames(n: int = 10, size: tuple[int, int] = (48, 64)) -> list[np.ndarray]:
    rng = np.random.default_rng(5)
    base = rng.integers(0, 200, (*size, 3), dtype=np.uint8)
    return [np.clip(base.astype(np.int16) + 4 * i, 0, 255).astype(np.uint8) for i in range(n)]


@pytest.mark.parametrize("content", ["auto", "full"])
@pytest.mark.parametrize("method", ["none", "rnn", "deflicker", "clahe"])
def test_a_frame_of_another_size_is_refused_naming_it(method: str, content: str) -> None:
    """With ``content="full"`` a frame of another size went on through the clip's state (the rnn's recurrence,
    deflicker's window) and came out at its new size, silently; with ``auto`` the refusal did not say which frame.
    One call is one clip of one size: both modes now refuse it, naming the frame."""
    frames = _frames()
    smaller = frames[7][:40, :60]
    built = colonlight.create_method(method)
    with pytest.raises(FrameShapeError, match=r"^frame 7: frame is 60x40, the clip started at 64x48: ") as info:
        list(colonlight.enhance_frames([*frames[:7], smaller, *frames[8:]], built, content=content))
    assert isinstance(info.value, ValueError)
    # the same frames each in a clip of their own are fine: a new call is a new clip
    assert len(list(colonlight.enhance_frames(frames, built, content=content))) == len(frames)
    assert len(list(colonlight.enhance_frames([smaller, smaller], built, content=content))) == 2


LAYOUTS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "negative-strides": lambda f: np.ascontiguousarray(f[::-1, ::-1])[::-1, ::-1],
    "every-other-pixel": lambda f: np.repeat(np.repeat(f, 2, axis=0), 2, axis=1)[::2, ::2],
    "reversed-channels-view": lambda f: np.ascontiguousarray(f[..., ::-1])[..., ::-1],
    "fortran-order": np.asfortranarray,
    "transposed-view": lambda f: np.ascontiguousarray(f.transpose(1, 0, 2)).transpose(1, 0, 2),
}


def _read_only(f: np.ndarray) -> np.ndarray:
    g = f.copy()
    g.flags.writeable = False
    return g


@pytest.mark.parametrize("method", ["none", "rnn", "he", "deflicker"])
def test_any_array_layout_gives_the_bytes_of_its_contiguous_copy(method: str) -> None:
    frames = _frames(8)
    built = colonlight.create_method(method)
    expected = [(r.frame.tobytes(), r.gamma) for r in colonlight.enhance_frames([f.copy() for f in frames], built)]
    for name, layout in {**LAYOUTS, "read-only": _read_only}.items():
        given = [layout(f) for f in frames]
        before = [g.copy() for g in given]
        out = list(colonlight.enhance_frames(given, built))
        assert [(r.frame.tobytes(), r.gamma) for r in out] == expected, name
        assert all(r.frame.shape == (48, 64, 3) and r.frame.dtype == np.uint8 for r in out), name
        assert all(np.array_equal(a, b) for a, b in zip(given, before, strict=True)), f"{name}: input changed"


@pytest.mark.parametrize("size", [float("nan"), float("inf"), 4.5, True])
def test_a_deflicker_window_that_is_not_a_whole_number_is_an_option_error(size: object) -> None:
    """``int(nan)`` raised a bare ValueError before the size was checked."""
    with pytest.raises(OptionError, match="size must be an integer"):
        create_method("deflicker", size=size)
