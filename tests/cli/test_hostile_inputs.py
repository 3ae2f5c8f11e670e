"""Hostile inputs of a hostile-input sweep, through real ``colonlight`` commands on real files: clips whose names
map to one output folder (each must get its own, none skipped or overwritten), a file named twice, a container
with a header and no frame, a Matroska file cut inside its header, a clip too short in time for the frame rate,
and frames too small for ``colonlight evaluate``'s optical flow (OpenCV's DIS refused them with a traceback, or
killed the process with SIGSEGV). Each bad one fails in one line naming the file and the cause; the rest goes on.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from ..media import make_clip, needs_ffmpeg

pytestmark = [needs_ffmpeg, pytest.mark.timeout(300)]

NONE = ("--method", "none", "-q", "-j", "1")
PNG = ("-c:v", "png")


def enhance(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["enhance", *args, *NONE])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.output
    assert "Traceback" not in result.output
    return result.exit_code, result.output


def sources(out: Path) -> dict[str, str]:
    """Output folder name -> the source its ``gammas.json`` was made from, for every clip of the manifest."""
    entries = json.loads((out / "manifest.json").read_text())["clips"]
    assert all(e["status"] == "done" and not e.get("skipped") for e in entries), entries
    return {e["clip"]: json.loads((out / e["clip"] / "gammas.json").read_text())["source"] for e in entries}


def test_clips_that_share_a_name_each_get_their_own_folder(tmp_path: Path) -> None:
    """``x/a.mp4`` and ``y/a.mp4`` both map to ``a-mp4``, as do ``a.mp4`` and ``a.MP4``; ``b.mp4`` would take
    ``b-mp4``, the plain name of ``b-mp4.mov``. Each clip is enhanced into a folder of its own, none skipped."""
    x, y, c = tmp_path / "x", tmp_path / "y", tmp_path / "c"
    make_clip(x / "a.mp4", 10, first_index=0)
    make_clip(y / "a.mp4", 10, first_index=100)
    for i, name in enumerate(["a.mp4", "a.MP4", "b.mp4", "b.mkv", "b-mp4.mov"]):
        make_clip(c / name, 10, first_index=200 + 20 * i)
    out = tmp_path / "out"
    code, output = enhance(str(x / "a.mp4"), str(y / "a.mp4"), "-o", str(out))
    assert code == 0, output
    assert sources(out) == {"a-mp4": str(x / "a.mp4"), "a-mp4-2": str(y / "a.mp4")}
    assert not [line for line in output.splitlines() if line.startswith("skipped")], output
    out = tmp_path / "out-c"
    code, output = enhance(str(c), "-o", str(out))
    assert code == 0, output
    assert sources(out) == {
        "a-mp4": str(c / "a.MP4"),  # sorted by name: upper case first
        "a-mp4-2": str(c / "a.mp4"),
        "b-mkv": str(c / "b.mkv"),
        "b-mp4": str(c / "b-mp4.mov"),  # a name no other clip wants is kept as it is
        "b-mp4-2": str(c / "b.mp4"),
    }
    assert not [line for line in output.splitlines() if line.startswith("skipped")], output


def test_no_clip_folder_is_inside_another_clips(tmp_path: Path) -> None:
    """``a.mp4`` beside a folder ``a/`` holding ``frames.mp4`` and ``b.mp4``: the clips ``a/frames`` and ``a/b``
    would be written inside ``a/`` (``a/frames/`` is where clip ``a`` puts its frames). The outer clip takes its
    suffix; every clip has a folder that holds no other clip's files."""
    videos = tmp_path / "videos"
    make_clip(videos / "a.mp4", 10, first_index=0)
    make_clip(videos / "a" / "frames.mp4", 10, first_index=100)
    make_clip(videos / "a" / "b.mp4", 10, first_index=200)
    out = tmp_path / "out"
    code, output = enhance(str(videos), "-o", str(out), "-j", "2")
    assert code == 0, output
    assert sources(out) == {
        "a-mp4": str(videos / "a.mp4"),
        "a/frames": str(videos / "a" / "frames.mp4"),
        "a/b": str(videos / "a" / "b.mp4"),
    }
    assert sorted(p.name for p in (out / "a").iterdir()) == ["b", "frames"]
    layout = sorted(p.name for p in (out / "a-mp4").iterdir())  # one clip's folder: gammas.json, frames/, ...
    assert "gammas.json" in layout
    assert sorted(p.name for p in (out / "a" / "frames").iterdir()) == layout  # nothing of clip a-mp4 in it


def test_a_file_named_twice_is_one_clip_under_its_own_name(tmp_path: Path) -> None:
    clip = make_clip(tmp_path / "videos" / "p7.mp4", 10)
    out = tmp_path / "out"
    code, output = enhance(str(clip), str(clip), str(clip.parent), "-o", str(out))
    assert code == 0, output
    assert sources(out) == {"p7": str(clip)}


def test_a_container_without_frames_or_cut_in_its_header_fails_in_one_clear_line(tmp_path: Path) -> None:
    """FFmpeg says "End of file" and "Input/output error" of these: the line says what that means for a file."""
    videos = tmp_path / "videos"
    make_clip(videos / "good.mkv", 10)
    make_clip(videos / "empty.mkv", 0)  # a Matroska header, no frame
    (videos / "cut.mkv").write_bytes((videos / "good.mkv").read_bytes()[:200])  # cut inside its header
    out = tmp_path / "out"
    code, output = enhance(str(videos), "-o", str(out))
    assert code == 1, output
    failed = {line.split()[1]: line for line in output.splitlines() if line.startswith("failed")}
    assert set(failed) == {f"{videos / 'empty.mkv'}:", f"{videos / 'cut.mkv'}:"}, output
    assert "no video frames: the file ends before its first frame" in failed[f"{videos / 'empty.mkv'}:"]
    assert "container cannot be read (Input/output error): truncated or corrupt?" in failed[f"{videos / 'cut.mkv'}:"]
    assert sorted(p.name for p in out.iterdir()) == [".colonlight.lock", "good", "manifest.json"]


def test_a_clip_too_short_in_time_for_the_rate_says_so(tmp_path: Path) -> None:
    """10 frames at 1000 fps last 10 ms: ``fps=18`` keeps none of them (as ``ffmpeg -vf fps=18`` does), which is
    not "only 0 frames" of a clip that has 10; ``--fps 0`` keeps all 10."""
    clip = make_clip(tmp_path / "fast.mp4", 10, fps=1000)
    out = tmp_path / "out"
    code, output = enhance(str(clip), "-o", str(out))
    assert code == 1, output
    assert f"{clip}: its 10 frames span too short a time for 18 fps: only 0 frame(s) at that rate" in output
    assert "(fps 0 keeps every frame)" in output
    assert not (out / "fast").exists()
    code, output = enhance(str(clip), "-o", str(out), "--fps", "0")
    assert code == 0, output
    assert json.loads((out / "fast" / "gammas.json").read_text())["frame_count"] == 10


def test_evaluate_fails_frames_too_small_for_optical_flow_alone(tmp_path: Path) -> None:
    """640x30 is 256x12 at the working size, on which OpenCV's DIS flow crashed the process (SIGSEGV); 1x1 it
    refused with a traceback that ended the evaluation. Both fail in one line, the good clip is reported. A real
    process, so that a crash is an exit status, not the end of the test run."""
    clips = tmp_path / "clips"
    make_clip(clips / "good.mp4", 10, size=(64, 48))
    make_clip(clips / "strip.mp4", 10, size=(640, 30))
    make_clip(clips / "dot.mkv", 10, size=(1, 1), codec_args=PNG)
    out = tmp_path / "out"
    args = ["evaluate", str(clips), "-o", str(out), "--methods", "none", "--no-colmap", "-q"]
    proc = subprocess.run(
        [sys.executable, "-m", "colonlight_cli.main", *args], capture_output=True, text=True, timeout=240, check=False
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 1, output
    assert "Traceback" not in output
    for name, size, working in (("strip.mp4", "640x30", "256x12"), ("dot.mkv", "1x1", "1x1")):
        lines = [line for line in output.splitlines() if name in line]
        assert len(lines) == 1 and lines[0].startswith("failed"), output
        assert f"frames of {size} ({working} at the working size) are too small to evaluate" in lines[0]
    record = json.loads((out / "results.json").read_text())
    assert [c["name"] for c in record["clips"]] == ["good"]
    assert sorted(f["clip"] for f in record["failures"]) == ["dot", "strip"]
    assert (out / "report.html").is_file()
