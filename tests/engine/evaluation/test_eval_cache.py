"""``colonlight.evaluation.cache``: a score is computed once per content, and any change of content is a miss."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from colonlight.evaluation.cache import ResultCache, content_key


def test_key_follows_content_params_dtype_and_shape() -> None:
    a = np.arange(12, dtype=np.uint8).reshape(3, 4)
    key = content_key("track", [a, None], {"fps": 18.0})
    assert key == content_key("track", [a.copy(), None], {"fps": 18.0})
    assert key == content_key("track", [np.asfortranarray(a), None], {"fps": 18.0})  # bytes, not memory layout
    others = [
        content_key("colmap", [a, None], {"fps": 18.0}),
        content_key("track", [a, None], {"fps": 9.0}),
        content_key("track", [a.reshape(4, 3), None], {"fps": 18.0}),
        content_key("track", [a.astype(np.uint16), None], {"fps": 18.0}),
        content_key("track", [a, a], {"fps": 18.0}),
        content_key("track", [a], {"fps": 18.0}),
    ]
    assert len({key, *others}) == 1 + len(others)


def test_computes_once_and_survives_a_new_cache(tmp_path: Path) -> None:
    calls: list[int] = []

    def compute() -> dict[str, float]:
        calls.append(1)
        return {"ate_mm": 1.25}

    frames = [np.zeros((2, 2, 3), np.uint8)]
    cache = ResultCache(tmp_path)
    assert cache.get_or_compute("track", frames, {}, compute) == {"ate_mm": 1.25}
    assert cache.get_or_compute("track", frames, {}, compute) == {"ate_mm": 1.25}
    assert (cache.hits, cache.misses, len(calls)) == (1, 1, 1)
    again = ResultCache(tmp_path)  # a later run: the entry is on disk
    assert again.get_or_compute("track", frames, {}, compute) == {"ate_mm": 1.25}
    assert (again.hits, len(calls)) == (1, 1)
    assert [p.name for p in (tmp_path / "track").iterdir()] == [f"{content_key('track', frames, {})}.json"]


def test_a_damaged_entry_is_recomputed(tmp_path: Path) -> None:
    frames = [np.ones((2, 2), np.uint8)]
    path = tmp_path / "track" / f"{content_key('track', frames, {})}.json"
    path.parent.mkdir(parents=True)
    path.write_text('{"ate_mm": 1.', encoding="utf-8")  # cut short
    cache = ResultCache(tmp_path)
    assert cache.get_or_compute("track", frames, {}, lambda: {"ate_mm": 2.0}) == {"ate_mm": 2.0}
    assert cache.misses == 1
    assert ResultCache(tmp_path).get_or_compute("track", frames, {}, lambda: {"ate_mm": 3.0}) == {"ate_mm": 2.0}
