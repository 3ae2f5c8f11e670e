"""colonlight.video against real clips made by tests/media.py, and against the ffmpeg tool itself.

The central claim: ``iter_video_frames(clip, fps=18)`` yields exactly the source frames that
``ffmpeg -i clip -vf fps=18`` outputs (same count, same frames, duplicates included), whatever the frame rate,
timestamps, container or start offset. Every clip frame shows its own index, so both sides are read back.
"""

from __future__ import annotations

import os
import tracemalloc
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from colonlight.errors import InputError
from colonlight.video import (
    DecodedFrame,
    DecodeReport,
    FpsSelector,
    VideoInfo,
    VideoWriter,
    is_video,
    iter_video_frames,
    probe_video,
    rescale_near,
)

from ...media import (
    corrupted_copy,
    ffmpeg_exe,
    ffmpeg_fps_indices,
    ffmpeg_frames,
    index_frame,
    make_clip,
    make_vfr_clip,
    needs_ffmpeg,
    read_index,
    remux,
    text_file,
    truncated_copy,
    vfr_times,
    with_rotation,
    zero_byte_file,
)

# name -> how to make it. Chosen so that each rule of the FFmpeg model matters somewhere (see the comments).
CLIPS = {
    "cfr25.mp4": lambda p: make_clip(p, 75, 25),
    "ntsc.mp4": lambda p: make_clip(p, 90, "30000/1001"),
    "cfr30.mkv": lambda p: make_clip(p, 60, 30),
    "cfr60.mp4": lambda p: make_clip(p, 120, 60),
    "slow10.mp4": lambda p: make_clip(p, 30, 10),  # slower than 18 fps: FFmpeg duplicates frames
    "bframes.mp4": lambda p: make_clip(  # reordered frames: decode order != presentation order
        p, 40, 25, codec_args=["-c:v", "libx264", "-bf", "3", "-crf", "12", "-pix_fmt", "yuv420p"]
    ),
    "vfr.mkv": lambda p: make_vfr_clip(p, vfr_times(80)),  # bursts and stalls, 1 ms time base
    "vfr.mp4": lambda p: make_vfr_clip(p, vfr_times(80, seed=3), time_base=Fraction(1, 90000)),
    # video starts 1.028 s into the file: FFmpeg shifts timestamps by the start time before rounding
    "late_start.mkv": lambda p: make_vfr_clip(p, [t + 1.0277 for t in vfr_times(60, seed=11)]),
    # audio starts at 0 and video at 0.02 s: the shift is the file's start (the audio's), not the video's
    "audio_first.mp4": lambda p: make_clip(p, 40, 30, audio=True, input_args=["-itsoffset", "0.02"]),
    # MPEG-TS (timestamps may jump): FFmpeg shifts by the start of the streams in use, the video's
    "audio.ts": lambda p: make_clip(p, 45, "30000/1001", audio=True),
    "raw.h264": lambda p: make_clip(p, 30, 25, output_args=["-f", "h264"]),  # no timestamps at all
    "mpeg4.avi": lambda p: make_clip(p, 30, 24, codec_args=["-c:v", "mpeg4", "-q:v", "2"]),
    "vp8.webm": lambda p: make_clip(p, 30, 25, codec_args=["-c:v", "libvpx", "-b:v", "1M"]),
    "mpeg2.mpg": lambda p: make_clip(p, 30, 25, codec_args=["-c:v", "mpeg2video", "-q:v", "2"]),
    "single.mp4": lambda p: make_clip(p, 1, 25),
}


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    if ffmpeg_exe() is None:
        pytest.skip("imageio-ffmpeg's ffmpeg binary is not available")
    root = tmp_path_factory.mktemp("clips")
    return {name: make(root / name) for name, make in CLIPS.items()}


def _ours(path: Path, fps: float | None = 18) -> list[DecodedFrame]:
    return list(iter_video_frames(path, fps))


# ------------------------------------------------------------------------------------- agreement with FFmpeg


@needs_ffmpeg
@pytest.mark.parametrize("name", [n for n in CLIPS if n != "single.mp4"])
def test_frame_choice_matches_ffmpeg_fps_filter(clips: dict[str, Path], name: str) -> None:
    path = clips[name]
    expected = ffmpeg_fps_indices(path, 18)
    frames = _ours(path, 18)
    assert [f.source_index for f in frames] == expected
    assert [read_index(f.image) for f in frames] == expected  # the pixels are those frames, too
    assert [f.index for f in frames] == list(range(len(frames)))
    assert all(f.time_s == pytest.approx(f.index / 18) for f in frames)


@needs_ffmpeg
def test_slow_clip_duplicates_frames_like_ffmpeg(clips: dict[str, Path]) -> None:
    frames = _ours(clips["slow10.mp4"], 18)
    sources = [f.source_index for f in frames]
    assert len(frames) == 54  # 3 s at 18 fps, up to the end of the last frame
    assert len(set(sources)) == 30 and len(sources) > len(set(sources))
    dup = next(i for i in range(1, len(frames)) if sources[i] == sources[i - 1])
    assert frames[dup].image is not frames[dup - 1].image  # a duplicate is a separate buffer
    np.testing.assert_array_equal(frames[dup].image, frames[dup - 1].image)


@needs_ffmpeg
@pytest.mark.parametrize("name", ["vfr.mkv", "audio.ts", "raw.h264", "bframes.mp4"])
def test_every_frame_mode_keeps_all_decoded_frames_in_order(clips: dict[str, Path], name: str) -> None:
    path = clips[name]
    reference = [read_index(f) for f in ffmpeg_frames(path)]
    for fps in (None, 0):
        frames = _ours(path, fps)
        assert [read_index(f.image) for f in frames] == reference == list(range(len(reference)))
        assert [f.source_index for f in frames] == [f.index for f in frames] == reference
        times = [f.source_time_s for f in frames]
        assert times[0] == pytest.approx(0.0, abs=1e-9) and times == sorted(times)
        assert all(f.time_s == f.source_time_s for f in frames)


@needs_ffmpeg
def test_source_times_follow_the_vfr_timestamps(clips: dict[str, Path]) -> None:
    frames = _ours(clips["late_start.mkv"], None)
    expected = vfr_times(60, seed=11)
    assert [f.source_time_s for f in frames] == pytest.approx([t - expected[0] for t in expected], abs=1.5e-3)
    chosen = _ours(clips["late_start.mkv"], 18)
    by_index = {f.source_index: f.source_time_s for f in frames}
    assert all(f.source_time_s == by_index[f.source_index] for f in chosen)


@needs_ffmpeg
@pytest.mark.parametrize(
    "codec_args",
    [
        ["-c:v", "libx264", "-pix_fmt", "yuv420p"],
        ["-c:v", "libx264", "-pix_fmt", "yuvj420p"],  # full range
        ["-c:v", "libx264", "-pix_fmt", "yuv444p10le"],
        ["-c:v", "libx264", "-pix_fmt", "yuv420p", "-colorspace", "bt709", "-color_range", "tv"],
        ["-c:v", "mjpeg", "-q:v", "3"],
        ["-c:v", "ffv1", "-pix_fmt", "gray"],
    ],
    ids=["yuv420p", "yuvj420p", "yuv444p10", "bt709", "mjpeg", "gray"],
)
def test_rgb_conversion_is_pyavs_to_ndarray(tmp_path: Path, codec_args: list[str]) -> None:
    """One swscale context per clip (not PyAV's new one, with new threads, for every frame) gives the very pixels
    of ``frame.to_ndarray(format="rgb24")``, whatever the pixel format, range or matrix."""
    path = make_clip(tmp_path / "c.mkv", 12, 25, size=(160, 96), codec_args=codec_args)
    ours = [f.image for f in iter_video_frames(path, None)]
    with av.open(str(path)) as c:
        theirs = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(ours) == len(theirs) == 12
    for a, b in zip(ours, theirs, strict=True):
        np.testing.assert_array_equal(a, b)


# ------------------------------------------------------------------------------------------------ FpsSelector


def _select(times: list[int], eof: int, tb: Fraction = Fraction(1, 1000)) -> list[tuple[int, int]]:
    """(source index, output pts) of each output frame for a clip with these pts and EOF, at 18 fps."""
    sel = FpsSelector(18, tb)
    out = []
    for t in times:
        out += sel.push(t)
        assert len(sel.pending) <= 2
    out += sel.close(eof)
    assert [d.index for d in out] == list(range(len(out)))
    return [(d.source_index, d.pts) for d in out]


def test_selector_drops_frames_of_a_faster_source() -> None:
    # 36 fps in a 1/36 time base: output k takes source 2k (source 2k+1 lands exactly on a half and rounds up)
    got = _select(list(range(8)), 8, tb=Fraction(1, 36))
    assert got == [(0, 0), (2, 1), (4, 2), (6, 3)]


def test_selector_duplicates_frames_of_a_slower_source_until_eof() -> None:
    # 9 fps: every frame twice; the last frame too, up to the EOF at 4/9 s (= output pts 8)
    got = _select([0, 111, 222, 333], 444)
    assert got == [(0, 0), (0, 1), (1, 2), (1, 3), (2, 4), (2, 5), (3, 6), (3, 7)]


def test_selector_starts_at_the_first_frames_rounded_pts() -> None:
    got = _select([1000, 1056], 1111)  # 18.0 and 19.008 -> output pts 18, 19
    assert got == [(0, 18), (1, 19)]


def test_selector_single_frame_fills_its_duration() -> None:
    assert _select([0], 1000) == [(0, k) for k in range(18)]  # a 1 s still: 18 copies
    assert _select([0], 28) == [(0, 0)]  # EOF at 0.504 output frames rounds to 1: one copy
    assert _select([0], 27) == []  # EOF at 0.486 rounds to 0, the frame's own slot: FFmpeg outputs nothing


def test_selector_eof_before_next_output_drops_the_last_frame() -> None:
    # last frame at 0.11 s -> pts 2; EOF at 0.12 s -> also 2: FFmpeg never outputs it
    assert _select([0, 55, 110], 120) == [(0, 0), (1, 1)]


def test_selector_rejects_push_after_close() -> None:
    sel = FpsSelector(18, Fraction(1, 1000))
    sel.close(0)
    with pytest.raises(RuntimeError):
        sel.push(0)


def test_rescale_near_rounds_halves_away_from_zero() -> None:
    tb, out = Fraction(1, 36), Fraction(1, 18)
    assert [rescale_near(v, tb, out) for v in (-3, -1, 0, 1, 2, 3)] == [-2, -1, 0, 1, 1, 2]


def test_selector_float_rates_snap_to_ntsc_fractions() -> None:
    assert FpsSelector(30000 / 1001, Fraction(1, 1000)).fps == Fraction(30000, 1001)
    assert FpsSelector(18.0, Fraction(1, 1000)).fps == 18
    with pytest.raises(ValueError):
        FpsSelector(-1, Fraction(1, 1000))


# --------------------------------------------------------------------------------------------------- rotation


@needs_ffmpeg
@pytest.mark.parametrize(("degrees", "hflip"), [(90, False), (-90, False), (180, False), (90, True), (0, True)])
def test_rotation_metadata_gives_upright_frames_like_ffmpeg(tmp_path: Path, degrees: int, hflip: bool) -> None:
    src = make_clip(tmp_path / "landscape.mp4", 6, 25, size=(160, 96))
    path = with_rotation(src, tmp_path / "phone.mp4", degrees, hflip)
    reference = list(ffmpeg_frames(path))
    frames = _ours(path, None)
    assert len(frames) == len(reference) == 6
    for ours, theirs in zip(frames, reference, strict=True):
        assert ours.image.shape == theirs.shape
        assert np.abs(ours.image.astype(int) - theirs.astype(int)).mean() < 1.0
    info = probe_video(path)
    assert (info.height, info.width) == reference[0].shape[:2]


@needs_ffmpeg
def test_rotation_is_a_real_quarter_turn(tmp_path: Path) -> None:
    """Independent of FFmpeg: a display matrix of 90 degrees counter-clockwise turns the picture that way."""
    src = make_clip(tmp_path / "landscape.mp4", 3, 25, size=(160, 96))
    path = with_rotation(src, tmp_path / "ccw.mp4", 90)
    plain = _ours(src, None)[0].image
    turned = _ours(path, None)[0].image
    np.testing.assert_array_equal(turned, np.rot90(plain, 1))
    info = probe_video(path)
    assert (info.width, info.height, info.rotation) == (96, 160, 270)


@needs_ffmpeg
def test_legacy_rotate_tag_is_honoured(clips: dict[str, Path], tmp_path: Path) -> None:
    """A bare ``rotate`` tag (clockwise degrees; mkv writes it as ROTATE) when there is no display matrix."""
    tagged = remux(clips["cfr30.mkv"], tmp_path / "tagged.mkv", output_args=["-metadata:s:v", "rotate=90"])
    plain = _ours(clips["cfr30.mkv"], None)[0].image
    np.testing.assert_array_equal(_ours(tagged, None)[0].image, np.rot90(plain, -1))
    assert probe_video(tagged).rotation == 90


# ----------------------------------------------------------------------------------------- probing by content


@needs_ffmpeg
def test_probe_video_reports_the_stream(clips: dict[str, Path]) -> None:
    info = probe_video(clips["audio_first.mp4"])
    assert isinstance(info, VideoInfo)
    assert (info.width, info.height, info.rotation, info.codec) == (128, 96, 0, "h264")
    assert info.has_audio and info.avg_fps == pytest.approx(30, rel=0.01)
    assert info.time_base is not None and info.duration_s == pytest.approx(1.35, abs=0.1)
    assert not probe_video(clips["cfr25.mp4"]).has_audio


@needs_ffmpeg
def test_videos_are_recognised_by_content_not_suffix(clips: dict[str, Path], tmp_path: Path) -> None:
    for name in ("cfr25.mp4", "vfr.mkv", "audio.ts", "mpeg4.avi", "vp8.webm", "mpeg2.mpg", "raw.h264"):
        assert is_video(clips[name]), name
    disguised = tmp_path / "recording.dat"
    disguised.write_bytes(clips["cfr30.mkv"].read_bytes())
    no_suffix = tmp_path / "recording"
    no_suffix.write_bytes(clips["cfr25.mp4"].read_bytes())
    for p in (disguised, no_suffix):
        assert is_video(p)
        assert [read_index(f.image) for f in iter_video_frames(p, None)][:3] == [0, 1, 2]


def test_non_videos_are_not_videos(tmp_path: Path) -> None:
    import cv2

    png_named_mp4 = tmp_path / "still.mp4"
    cv2.imencode(".png", index_frame(3))[1].tofile(str(png_named_mp4))
    for p in (
        zero_byte_file(tmp_path / "empty.mp4"),
        text_file(tmp_path / "notes.mp4"),
        text_file(tmp_path / "notes.txt"),  # FFmpeg would open this as "tty" video
        png_named_mp4,
        tmp_path / "missing.mp4",
        tmp_path,
    ):
        assert not is_video(p), p
        with pytest.raises(InputError) as err:
            probe_video(p)
        _assert_one_line_naming(err.value, p)


# ----------------------------------------------------------------------------------------------- bad inputs


def _assert_one_line_naming(err: BaseException, path: Path) -> None:
    msg = str(err)
    assert str(path) in msg and "\n" not in msg and len(msg) < 400, msg


@pytest.mark.parametrize(
    ("make", "cause"),
    [
        (lambda d: zero_byte_file(d / "empty.mp4"), "empty file"),
        (lambda d: text_file(d / "notes.mov"), "not a video"),
        (lambda d: d / "gone.mp4", "not found"),
        (lambda d: d, "directory"),
    ],
)
def test_bad_inputs_raise_one_line_input_errors(tmp_path: Path, make: Callable[[Path], Path], cause: str) -> None:
    path = make(tmp_path)
    with pytest.raises(InputError) as err:
        next(iter_video_frames(path))
    _assert_one_line_naming(err.value, path)
    assert cause in str(err.value)


@needs_ffmpeg
def test_truncated_mp4_is_reported_before_any_frame(clips: dict[str, Path], tmp_path: Path) -> None:
    faststart = make_clip(tmp_path / "fs.mp4", 60, 25, output_args=["-movflags", "+faststart"])
    cut = truncated_copy(faststart, tmp_path / "cut fs.mp4", 0.6)  # index intact, media data cut
    with pytest.raises(InputError, match="truncated") as err:
        next(iter_video_frames(cut))
    _assert_one_line_naming(err.value, cut)
    no_index = truncated_copy(clips["cfr25.mp4"], tmp_path / "cut.mp4", 0.6)  # index at the end: lost
    with pytest.raises(InputError, match="moov") as err:
        probe_video(no_index)
    _assert_one_line_naming(err.value, no_index)


@needs_ffmpeg
def test_corrupt_video_decodes_past_the_damage_like_ffmpeg(clips: dict[str, Path], tmp_path: Path) -> None:
    """A third of the file overwritten: the packets the decoder rejects are skipped, as ffmpeg skips them, and
    every frame ffmpeg gets out of the file is ours (tests/engine/video/test_decode_damage.py compares the pixels
    too)."""
    bad = corrupted_copy(clips["cfr60.mp4"], tmp_path / "corrupt.mp4", start=0.3, length=0.3)
    report = DecodeReport()
    got = [read_index(f.image) for f in iter_video_frames(bad, None, report=report)]
    assert got == [read_index(f) for f in ffmpeg_frames(bad)]
    assert got[:5] == [0, 1, 2, 3, 4] and report.damaged > 0


@needs_ffmpeg
def test_one_frame_clip_fails_min_frames_before_yielding(clips: dict[str, Path]) -> None:
    single = clips["single.mp4"]
    assert len(_ours(single, None)) == 1  # fine without a minimum
    with pytest.raises(InputError, match="too short") as err:
        next(iter_video_frames(single, 18, min_frames=2))
    _assert_one_line_naming(err.value, single)
    assert len(list(iter_video_frames(clips["cfr25.mp4"], 18, min_frames=2))) == 54


@needs_ffmpeg
@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root reads files whatever their mode")
def test_unreadable_file(clips: dict[str, Path], tmp_path: Path) -> None:
    p = tmp_path / "locked.mp4"
    p.write_bytes(clips["cfr25.mp4"].read_bytes())
    p.chmod(0)
    assert not is_video(p)
    with pytest.raises(InputError, match="permission denied"):
        probe_video(p)


def test_permission_errors_from_ffmpeg_become_input_errors(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same path as above, for machines where the tests run as root."""
    p = text_file(tmp_path / "locked.mp4")

    def denied(*args: object, **kwargs: object) -> None:
        raise av.error.PermissionError(13, "Permission denied", str(p))

    monkeypatch.setattr(av, "open", denied)
    with pytest.raises(InputError, match="permission denied") as err:
        next(iter_video_frames(p))
    _assert_one_line_naming(err.value, p)
    assert not is_video(p)


@needs_ffmpeg
def test_file_vanishing_before_and_during_a_run(clips: dict[str, Path], tmp_path: Path) -> None:
    p = tmp_path / "moving.mp4"
    p.write_bytes(clips["cfr25.mp4"].read_bytes())
    probe_video(p)
    frames = iter_video_frames(p)
    first = next(frames)
    p.unlink()  # an open file stays readable on POSIX: the run completes
    assert 1 + sum(1 for _ in frames) == 54 and first.index == 0
    with pytest.raises(InputError, match="not found") as err:
        next(iter_video_frames(p))  # gone before the run: one clear line
    _assert_one_line_naming(err.value, p)


@needs_ffmpeg
def test_paths_with_spaces_and_non_ascii(clips: dict[str, Path], tmp_path: Path) -> None:
    folder = tmp_path / "Patient Ä 患者 01"
    folder.mkdir()
    p = folder / "Koloskopie – Durchgang ü 1.mp4"
    p.write_bytes(clips["cfr25.mp4"].read_bytes())
    assert is_video(p) and probe_video(p).path == p
    assert len(_ours(p, 18)) == 54


# ------------------------------------------------------------------------------------------------- streaming


@needs_ffmpeg
def test_memory_is_constant_in_clip_length(tmp_path: Path) -> None:
    def peak(n_frames: int) -> int:
        path = make_clip(tmp_path / f"long{n_frames}.mkv", n_frames, 60, size=(320, 240))
        tracemalloc.start()
        for _ in iter_video_frames(path, 18):
            pass
        size = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return size

    short, long = peak(60), peak(900)
    assert long < short + 2 * 320 * 240 * 3, (short, long)  # 15x the frames, not 15x the memory


@needs_ffmpeg
def test_stopping_early_closes_cleanly(clips: dict[str, Path]) -> None:
    frames = iter_video_frames(clips["cfr60.mp4"])
    assert next(frames).index == 0
    frames.close()


# ---------------------------------------------------------------------------------------------------- writer


@needs_ffmpeg
def test_writer_round_trip_through_our_reader_and_ffmpeg(tmp_path: Path) -> None:
    path = tmp_path / "out ü.mp4"
    with VideoWriter(path, fps=18) as w:
        for i in range(20):
            w.write(index_frame(i, 128, 96))
    assert w.frames_written == 20 and path.is_file()
    assert [read_index(f.image) for f in iter_video_frames(path, None)] == list(range(20))
    assert [f.source_index for f in iter_video_frames(path, 18)] == list(range(20))
    assert ffmpeg_fps_indices(path, 18) == list(range(20))
    assert probe_video(path).avg_fps == pytest.approx(18)
    assert not [p for p in tmp_path.iterdir() if p != path]  # no temporaries left


def test_writer_pads_odd_sizes_and_keeps_colours(tmp_path: Path) -> None:
    img = np.zeros((47, 65, 3), np.uint8)
    img[:, :32] = (200, 60, 40)
    img[:, 32:] = (30, 160, 220)
    path = tmp_path / "odd.mp4"
    with VideoWriter(path, fps=25) as w:
        for _ in range(3):
            w.write(img)
    out = next(iter_video_frames(path, None)).image
    assert out.shape == (48, 66, 3)
    assert np.abs(out[20, 10].astype(int) - (200, 60, 40)).max() <= 4
    assert np.abs(out[20, 50].astype(int) - (30, 160, 220)).max() <= 4


def test_writer_leaves_nothing_on_error_or_abort(tmp_path: Path) -> None:
    path = tmp_path / "failed.mp4"
    with pytest.raises(KeyError), VideoWriter(path, fps=18) as w:
        w.write(index_frame(0))
        raise KeyError("boom")
    w2 = VideoWriter(path, fps=18)
    w2.write(index_frame(0))
    w2.abort()
    w2.abort()  # idempotent
    with pytest.raises(RuntimeError):
        w2.write(index_frame(1))
    with VideoWriter(path, fps=18):
        pass  # no frames: no file
    assert list(tmp_path.iterdir()) == []


def test_writer_rejects_bad_frames(tmp_path: Path) -> None:
    path = tmp_path / "bad.mp4"
    with pytest.raises(InputError), VideoWriter(path, fps=18) as w:
        w.write(index_frame(0))
        w.write(index_frame(1, 64, 48))
    with pytest.raises(InputError):
        VideoWriter(path, fps=18).write(np.zeros((8, 8), np.uint8))
    assert list(tmp_path.iterdir()) == []
