"""What `colonlight evaluate`'s tracker is told is scene: the content area `enhance` finds (or the mask given as
``content``), nothing for a clip without a border, so such a clip is tracked and cached exactly as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from colonlight.content import parse_content
from colonlight.content_area import ContentArea
from colonlight.content_mask import write_content_mask
from colonlight.evaluation.clips import EvalClip
from colonlight.evaluation.runner import scene_mask
from colonlight.synth.overlay import OverlaySpec


def _frames(n: int = 20) -> list[np.ndarray]:
    rng = np.random.default_rng(4)
    return [rng.integers(40, 200, (96, 128, 3), dtype=np.uint8) for _ in range(n)]


def test_a_bordered_clip_gives_its_content_area_and_a_plain_one_nothing(tmp_path: Path) -> None:
    plain = _frames()
    spec = OverlaySpec(border="round", fov=0.9, text=False)
    framed = [spec.apply(f) for f in plain]
    assert scene_mask(EvalClip("plain", "constructed", plain), "auto") is None
    found = scene_mask(EvalClip("framed", "constructed", framed), "full")  # whatever the methods are shown
    assert np.array_equal(scene_mask(EvalClip("framed", "constructed", framed), " AUTO"), found)  # a word
    fov, _ = spec.masks(96, 128)
    assert found is not None and (found == fov).mean() > 0.99
    given = np.zeros((96, 128), bool)
    given[10:80, 20:100] = True
    write_content_mask(tmp_path / "m.pgm", ContentArea(given, np.zeros_like(given)))
    assert np.array_equal(scene_mask(EvalClip("framed", "constructed", framed), str(tmp_path / "m.pgm")), given)
    write_content_mask(tmp_path / "small.pgm", ContentArea(given[:50], np.zeros_like(given[:50])))
    assert scene_mask(EvalClip("framed", "constructed", framed), str(tmp_path / "small.pgm")) is None


def test_a_parsed_mask_is_the_one_tracked_even_if_its_file_changes(tmp_path: Path) -> None:
    """evaluate records the SHA-256 of the mask it parsed; the tracker must be told that mask's area too, not what
    the file holds by the time a clip is scored."""
    frames = _frames(4)
    given = np.zeros((96, 128), bool)
    given[10:80, 20:100] = True
    path = tmp_path / "m.pgm"
    write_content_mask(path, ContentArea(given, np.zeros_like(given)))
    parsed = parse_content(path)
    edited = np.zeros_like(given)
    edited[30:60, 40:90] = True
    write_content_mask(path, ContentArea(edited, np.zeros_like(edited)))
    assert np.array_equal(scene_mask(EvalClip("c", "constructed", frames), parsed), given)
    assert np.array_equal(scene_mask(EvalClip("c", "constructed", frames), str(path)), edited)  # a path: read now
