"""Behaviour sweep 5 (engine): the same inputs give the same output bytes.

``enhanced.mp4`` of the same frames differed from run to run, in one process and in the CLI (`colonlight
enhance` of a 96x80 clip with ``--video``: one run in five wrote another video, the frames and gammas.json the
same): x264's macroblock-tree rate control (``mbtree``, on in the ``medium`` preset) gave different bytes for the
same frames, even on one thread (7 different videos in 40 encodes at 96x80, 2 in 40 at 320x240). The writer now
runs x264 without it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from colonlight.video import VideoWriter

from ..media import index_frame


def test_writer_gives_the_same_bytes_every_time_in_one_process(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    frames = [
        np.clip(index_frame(i, 96, 80).astype(int) + rng.integers(-20, 20, (80, 96, 3)), 0, 255).astype(np.uint8)
        for i in range(26)
    ]
    digests = set()
    for run in range(30):
        path = tmp_path / f"{run % 2}.mp4"
        with VideoWriter(path, fps=18) as writer:
            for frame in frames:
                writer.write(frame)
        digests.add(hashlib.sha256(path.read_bytes()).hexdigest())
    assert len(digests) == 1, f"{len(digests)} different videos of the same frames in 30 encodes"
