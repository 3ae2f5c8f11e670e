"""Timestamps as FFmpeg sees them: joined recordings, wraps and jumps still give ``fps=18``'s frame choice.

The ``ffmpeg`` tool corrects packet timestamps before decoding (``ts_fixup`` in ``fftools/ffmpeg_demux.c``): in
MPEG-TS/PS a jump of more than 10 s, or back by more than 0.1 s, is bridged so that the stream continues; the
33-bit wrap is undone. Two recordings joined end to end (``cat a.ts b.ts``) used to lose the whole second half
here, silently (its timestamps start again, so the fps filter dropped them all). Each clip below is compared, frame
by frame, with what the ffmpeg binary outputs for ``-vf fps=18`` on the same file.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.video import DecodeReport, iter_video_frames

from ...media import ffmpeg_exe, ffmpeg_fps_indices, joined, make_clip, make_vfr_clip, needs_ffmpeg, read_index

WRAP_S = 2**33 / 90000  # MPEG-TS timestamps are 33 bits at 90 kHz: they wrap after 26.5 hours
BFRAMES = ("-c:v", "libx264", "-bf", "3", "-crf", "12", "-pix_fmt", "yuv420p")
MPEG2 = ("-c:v", "mpeg2video", "-q:v", "2")


def _offset(seconds: float) -> list[str]:
    return ["-output_ts_offset", f"{seconds:.6f}"]


# name -> how to make it from a folder; second parts show frame indices from 100 on
CLIPS: dict[str, Callable[[Path], Path]] = {
    # two recordings end to end: the second starts again at the muxer's 1.4 s
    "joined.ts": lambda d: joined(
        [make_clip(d / "a.ts", 30, 25), make_clip(d / "b.ts", 30, 25, first_index=100)], d / "joined.ts"
    ),
    # the same with B-frames (reordered pts), audio, and a different rate in the second part
    "joined_bframes_audio.ts": lambda d: joined(
        [
            make_clip(d / "c.ts", 40, 25, codec_args=BFRAMES, audio=True),
            make_clip(d / "e.ts", 40, 30, codec_args=BFRAMES, audio=True, first_index=100),
        ],
        d / "joined_bframes_audio.ts",
    ),
    # a 60 s jump forward: more than 10 s, so FFmpeg bridges it (no minute of repeats)
    "jump60.ts": lambda d: joined(
        [make_clip(d / "f.ts", 30, 25), make_clip(d / "g.ts", 30, 25, first_index=100, output_args=_offset(60))],
        d / "jump60.ts",
    ),
    # 30 s backwards
    "back30.ts": lambda d: joined(
        [make_clip(d / "h.ts", 30, 25, output_args=_offset(30)), make_clip(d / "i.ts", 30, 25, first_index=100)],
        d / "back30.ts",
    ),
    # half a second backwards (more than 0.1 s: bridged) and 0.05 s backwards (not: those frames are dropped)
    "back0.5.ts": lambda d: joined(
        [make_clip(d / "j.ts", 25, 25), make_clip(d / "k.ts", 25, 25, first_index=100, output_args=_offset(0.5))],
        d / "back0.5.ts",
    ),
    "back0.05.ts": lambda d: joined(
        [make_clip(d / "l.ts", 25, 25), make_clip(d / "m.ts", 25, 25, first_index=100, output_args=_offset(0.95))],
        d / "back0.05.ts",
    ),
    # the 33-bit wrap 1.5 s into the clip, alone and followed by a recording that starts at 0
    "wrap.ts": lambda d: make_clip(d / "wrap.ts", 75, 25, output_args=_offset(WRAP_S - 1.5)),
    "wrap_joined.ts": lambda d: joined(
        [
            make_clip(d / "n.ts", 75, 25, output_args=_offset(WRAP_S - 1.5)),
            make_clip(d / "o.ts", 30, 25, first_index=100),
        ],
        d / "wrap_joined.ts",
    ),
    # MPEG program streams join the same way (DVD/camcorder .mpg files)
    "joined.mpg": lambda d: joined(
        [
            make_clip(d / "p.mpg", 30, 25, codec_args=MPEG2),
            make_clip(d / "q.mpg", 30, 25, codec_args=MPEG2, first_index=100),
        ],
        d / "joined.mpg",
    ),
    # formats without timestamp jumps keep a gap: FFmpeg repeats the frame before it
    "gap12.mkv": lambda d: make_vfr_clip(d / "gap12.mkv", [0, 0.04, 0.08, 12.0, 12.04, 12.08]),
    "gap12.mp4": lambda d: make_vfr_clip(d / "gap12.mp4", [0, 0.04, 0.08, 12.0, 12.04, 12.08]),
}


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    if ffmpeg_exe() is None:
        pytest.skip("imageio-ffmpeg's ffmpeg binary is not available")
    root = tmp_path_factory.mktemp("timestamps")
    return {name: make(root) for name, make in CLIPS.items()}


@needs_ffmpeg
@pytest.mark.parametrize("name", list(CLIPS))
def test_frame_choice_matches_ffmpeg_fps_filter(clips: dict[str, Path], name: str) -> None:
    expected = ffmpeg_fps_indices(clips[name], 18)
    ours = [read_index(f.image) for f in iter_video_frames(clips[name], 18)]
    assert ours == expected
    if "joined" in name or name.startswith(("jump", "back0.5", "back30")):
        assert any(i >= 100 for i in ours), "the second recording is kept"


@needs_ffmpeg
def test_joined_recordings_keep_both_halves_and_say_so(clips: dict[str, Path]) -> None:
    report = DecodeReport()
    frames = list(iter_video_frames(clips["joined.ts"], None, report=report))
    assert [read_index(f.image) for f in frames] == [*range(30), *range(100, 130)]
    times = [f.source_time_s for f in frames]
    assert times == sorted(times) and times[30] == pytest.approx(30 / 25)  # continues where the first ended
    assert report.discontinuities == 1 and not report.truncated
    assert any("discontinuit" in w for w in report.warnings)
    plain = DecodeReport()
    list(iter_video_frames(clips["wrap.ts"], 18, report=plain))
    assert plain.discontinuities == 0 and plain.warnings == []  # a wrap is no discontinuity


@needs_ffmpeg
def test_cli_enhances_both_halves_of_a_joined_ts(clips: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["enhance", str(clips["joined.ts"]), "-o", str(out), "--method", "none", "-q"])
    assert result.exit_code == 0, result.output
    gammas = json.loads((out / "joined" / "gammas.json").read_text())
    assert gammas["frame_count"] == len(ffmpeg_fps_indices(clips["joined.ts"], 18)) == 43
    assert "truncated" not in gammas
