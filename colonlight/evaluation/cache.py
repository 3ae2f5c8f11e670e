"""A content-addressed cache of the expensive scores (tracking, COLMAP), so that re-running an evaluation only
computes what is new.

The key is the SHA-256 of everything the score depends on: the enhanced frames' bytes, the clip's ground truth
(depth, poses, intrinsics) and the scorer's settings. A result can therefore never be stale: a changed model
gives other frames and another key. Methods themselves are always re-run (they are cheap, and their cost is
measured afresh); adding a method to an evaluation, or re-running one that was interrupted, costs only the scores
that are missing. Entries are JSON files written atomically, so an interrupted run leaves no half-written entry.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import read_json, write_json_atomic


def content_key(kind: str, arrays: Iterable[np.ndarray | None], params: dict[str, Any]) -> str:
    """SHA-256 over ``kind``, ``params`` (as sorted JSON) and each array's dtype, shape and bytes."""
    h = hashlib.sha256()
    h.update(json.dumps({"kind": kind, **params}, sort_keys=True, default=str).encode())
    for a in arrays:
        if a is None:
            h.update(b"none")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


class ResultCache:
    """JSON results under ``folder/<kind>/<key>.json``."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.hits = 0
        self.misses = 0

    def get_or_compute(
        self,
        kind: str,
        arrays: Iterable[np.ndarray | None],
        params: dict[str, Any],
        compute: Callable[[], dict[str, Any]],
    ) -> dict[str, Any]:
        """The cached result for this content, else ``compute()`` (stored before it is returned)."""
        path = self.folder / kind / f"{content_key(kind, arrays, params)}.json"
        try:
            value: dict[str, Any] = read_json(path)
        except (OSError, ValueError):
            pass
        else:
            self.hits += 1
            return value
        self.misses += 1
        value = compute()
        write_json_atomic(path, value)
        return value
