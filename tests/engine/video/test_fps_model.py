"""The model of FFmpeg's ``fps`` filter on its own (``colonlight.fps``): pure timestamp arithmetic, tested without
PyAV, numpy or a video file. The expected choices were recorded from the ffmpeg binary (``ffmpeg -i clip.mkv
-vf fps=18``) on the clips whose timestamps (Matroska, 1/1000 s) are listed here; tests/engine/video/test_video.py
checks the same choice against the binary on real files of many kinds."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from fractions import Fraction

import pytest

from colonlight.fps import FpsRun, FpsSelector, as_fraction, rescale_near

MS = Fraction(1, 1000)

# name -> (frame pts in ms, duration of the last frame in ms, source indices ffmpeg -vf fps=18 output)
RECORDED: dict[str, tuple[list[int], int, list[int]]] = {
    "25fps": ([40 * i for i in range(25)], 40, [0, 2, 3, 4, 6, 7, 9, 10, 11, 13, 14, 15, 17, 18, 20, 21, 22, 24]),
    "10fps": ([100 * i for i in range(8)], 100, [0, 0, 1, 1, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7]),
    "60fps": (
        [0, 17, 33, 50, 67, 83, 100, 117, 133, 150, 167, 183, 200, 217, 233]
        + [250, 267, 283, 300, 317, 333, 350, 367, 383, 400, 417, 433, 450, 467, 483],
        16,
        [1, 5, 8, 11, 14, 18, 21, 24, 28],
    ),
    "29.97fps": (
        [0, 33, 67, 100, 133, 167, 200, 234, 267, 300, 334, 367, 400, 434, 467]
        + [501, 534, 567, 601, 634, 667, 701, 734, 767, 801, 834, 868, 901, 934, 968],
        33,
        [0, 2, 4, 5, 7, 9, 10, 12, 14, 15, 17, 19, 20, 22, 24, 25, 27, 29],
    ),
    "one frame": ([0], 40, [0]),
    "vfr": ([0, 30, 110, 120, 400, 410, 1000], 33, [0, 1, 3, 3, 3, 3, 3, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 6]),
}


def choose(pts: list[int], last_duration: int, fps: float = 18) -> list[int]:
    selector = FpsSelector(fps, MS)
    out = [d.source_index for p in pts for d in selector.push(p)]
    return out + [d.source_index for d in selector.close(pts[-1] + last_duration)]


@pytest.mark.parametrize("name", list(RECORDED))
def test_choice_is_ffmpegs(name: str) -> None:
    pts, last, expected = RECORDED[name]
    assert choose(pts, last) == expected


@pytest.mark.parametrize("name", list(RECORDED))
def test_runs_expand_to_the_same_decisions(name: str) -> None:
    pts, last, _ = RECORDED[name]
    a, b = FpsSelector(18, MS), FpsSelector(18, MS)
    plain = [d for p in pts for d in a.push(p)] + a.close(pts[-1] + last)
    runs = [r for p in pts for r in b.push_runs(p)] + b.close_runs(pts[-1] + last)
    assert [d for r in runs for d in r.decisions()] == plain
    assert [d.index for d in plain] == list(range(len(plain)))  # output indices count up, no gaps


def test_a_long_gap_is_one_run_in_constant_memory() -> None:
    selector = FpsSelector(18, MS)
    runs = selector.push_runs(0) + selector.push_runs(60_000) + selector.close_runs(60_040)
    assert runs[0] == FpsRun(index=0, source_index=0, pts=0, count=1080)  # 60 s at 18 fps, a few integers
    assert selector.pending == ()


def test_at_most_two_frames_are_held() -> None:
    selector = FpsSelector(18, MS)
    for p in range(0, 2000, 7):
        selector.push(p)
        assert len(selector.pending) <= 2


def test_rounding_and_rates() -> None:
    assert rescale_near(1, Fraction(1, 2), Fraction(1, 1)) == 1  # a half rounds away from zero
    assert rescale_near(-1, Fraction(1, 2), Fraction(1, 1)) == -1
    assert as_fraction(30000 / 1001) == Fraction(30000, 1001)  # floats snap to NTSC ratios
    assert as_fraction(25.0) == 25
    with pytest.raises(ValueError, match="positive"):
        as_fraction(0)
    selector = FpsSelector(18, MS)
    selector.close(0)
    with pytest.raises(RuntimeError):
        selector.push(1)


def test_the_model_runs_without_pyav_or_numpy() -> None:
    """``colonlight.fps`` imports nothing but the standard library: it works where PyAV, numpy and OpenCV are not
    importable (checked in a fresh interpreter that refuses them)."""
    code = textwrap.dedent(
        """
        import sys

        class Refuse:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("av", "numpy", "cv2", "torch"):
                    raise ImportError(f"{name} refused")

        sys.meta_path.insert(0, Refuse())
        from fractions import Fraction
        from colonlight.fps import FpsSelector
        s = FpsSelector(18, Fraction(1, 1000))
        out = [d.source_index for p in range(0, 800, 100) for d in s.push(p)] + [d.source_index for d in s.close(800)]
        assert not any(m.split(".")[0] in ("av", "numpy", "cv2") for m in sys.modules), sorted(sys.modules)
        print(out)
        """
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == str(RECORDED["10fps"][2])
