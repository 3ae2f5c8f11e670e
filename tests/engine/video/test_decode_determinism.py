"""``enhanced.mp4`` is byte-identical across runs with the same inputs and settings, on any machine.

x264 used to take one thread, and one slice per frame, per core the process may use (``sched_getaffinity``):
two runs differed as soon as they saw different cores (a container's CPU limit, ``taskset``, another machine).
The writer now fixes its threads and writes no muxer version. Two real ``colonlight enhance`` processes, one
pinned to a single core, must write the same bytes.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import av
import pytest

from colonlight.video import VideoWriter

from ...commands import colonlight_command
from ...media import index_frame, make_clip, needs_ffmpeg

CORES = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
needs_two_cores = pytest.mark.skipif(len(CORES) < 2, reason="needs two usable cores to vary the encoder's view")


def _first_difference(a: Path, b: Path) -> str:
    """Where two mp4s' encoded streams part (packet index, size, key flag), so that a rare mismatch in CI says
    whether the encoder or the muxer made it."""
    with av.open(str(a)) as ca, av.open(str(b)) as cb:
        pa = [bytes(p) for p in ca.demux(video=0) if p.size]
        pb = [bytes(p) for p in cb.demux(video=0) if p.size]
    for i, (x, y) in enumerate(zip(pa, pb, strict=False)):
        if x != y:
            at = next((k for k, (u, v) in enumerate(zip(x, y, strict=False)) if u != v), min(len(x), len(y)))
            return f"packet {i} of {len(pa)}/{len(pb)} differs: {len(x)} vs {len(y)} bytes, first at byte {at}"
    return f"streams equal over {min(len(pa), len(pb))} packets ({len(pa)} vs {len(pb)}): the container differs"


@needs_ffmpeg
@needs_two_cores
@pytest.mark.timeout(600)
def test_two_cli_runs_write_identical_videos(tmp_path: Path) -> None:
    clip = make_clip(tmp_path / "clip.mp4", 40, 25, size=(640, 360))
    outputs = []
    for name, cores in (("all", CORES), ("one", CORES[:1])):
        out = tmp_path / name
        cmd = colonlight_command(
            "enhance", clip, "-o", out, "--method", "gamma", "--gamma", "0.7", "--video", "--no-frames", "-q"
        )
        proc = subprocess.run(
            cmd, capture_output=True, text=True, timeout=300, preexec_fn=lambda c=set(cores): os.sched_setaffinity(0, c)
        )
        assert proc.returncode == 0, proc.stderr
        outputs.append((out / "clip" / "enhanced.mp4").read_bytes())
    assert len(outputs[0]) > 1000
    assert outputs[0] == outputs[1], _first_difference(
        tmp_path / "all/clip/enhanced.mp4", tmp_path / "one/clip/enhanced.mp4"
    )


@needs_two_cores
def test_writer_bytes_do_not_depend_on_the_cores_it_sees(tmp_path: Path) -> None:
    frames = [index_frame(i, 320, 240) for i in range(30)]
    written = []
    before = os.sched_getaffinity(0)
    try:
        for cores in (set(CORES), set(CORES[:1])):
            os.sched_setaffinity(0, cores)
            path = tmp_path / f"{len(cores)}.mp4"
            with VideoWriter(path, fps=18) as w:
                for f in frames:
                    w.write(f)
            written.append(path.read_bytes())
    finally:
        os.sched_setaffinity(0, before)
    assert written[0] == written[1], _first_difference(tmp_path / f"{len(CORES)}.mp4", tmp_path / "1.mp4")
    assert b"Lavf" not in written[0]  # no muxer version string
