"""The pieces of `colonlight stream` on their own: frame choice on arrival, the dropping hand-off, latency
statistics, the y4m writer (read back by the ffmpeg binary), source parsing and device probing."""

from __future__ import annotations

import io
import socket
import subprocess
import threading
import time
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from colonlight.errors import InputError
from colonlight.live.choice import FrameChoice
from colonlight.live.handoff import FrameHandoff, HandoffClosed
from colonlight.live.outputs import FrameFolder, Y4mPipe
from colonlight.live.source import parse_source, probe_device
from colonlight.live.stats import LatencyStats
from colonlight.video import FpsSelector

from ...media import X264, ffmpeg_decoded, ffmpeg_exe, index_frame, make_clip, needs_ffmpeg, read_index, vfr_times
from ...ports import free_port

# ----------------------------------------------------------------------------------------------- frame choice


def _exact(pts: list[int], tb: Fraction, fps: float, last_duration: int) -> list[int]:
    sel = FpsSelector(fps, tb)
    out = [d.source_index for p in pts for d in sel.push(p)]
    return out + [d.source_index for d in sel.close(pts[-1] + last_duration)]


def _on_arrival(pts: list[int], tb: Fraction, fps: float, durations: list[int]) -> tuple[list[int], list[int]]:
    """Source index of every output frame, and how many source frames had arrived when each was decided."""
    choice = FrameChoice(fps)
    choice.start_segment(tb)
    chosen: dict[int, int] = {}
    arrived_at: dict[int, int] = {}
    for i, (p, d) in enumerate(zip(pts, durations, strict=True)):
        for c in choice.push(p, p + d):
            chosen[c.index] = c.source_index
            arrived_at[c.index] = i + 1
    for c in choice.end_segment(pts[-1] + durations[-1]):
        chosen[c.index] = c.source_index
        arrived_at[c.index] = len(pts)
    assert sorted(chosen) == list(range(len(chosen)))
    return [chosen[k] for k in sorted(chosen)], [arrived_at[k] for k in sorted(chosen)]


@pytest.mark.parametrize("rate", [Fraction(25), Fraction(30), Fraction(30000, 1001), Fraction(60), Fraction(10)])
def test_constant_rate_choice_is_ffmpegs_and_decided_on_arrival(rate: Fraction) -> None:
    tb = Fraction(1, 90000)
    step = int(90000 / rate)
    pts = [i * step for i in range(120)]
    chosen, arrived = _on_arrival(pts, tb, 18, [step] * len(pts))
    assert chosen == _exact(pts, tb, 18, step)
    # every output frame is decided as soon as its own source frame is in: no wait for the next one
    assert all(n == src + 1 for n, src in zip(arrived, chosen, strict=True))


def test_variable_rate_choice_stays_close_to_ffmpegs() -> None:
    tb = Fraction(1, 1000)
    times = vfr_times(200)
    pts = [round(t * 1000) for t in times]
    durations = [max(1, b - a) for a, b in zip(pts, pts[1:], strict=False)] + [40]
    chosen, _ = _on_arrival(pts, tb, 18, [40] * len(pts))  # predictions deliberately off (25 fps guess)
    exact = _exact(pts, tb, 18, 40)
    assert len(chosen) == len(exact)  # the same slots, one frame each
    assert max(abs(a - b) for a, b in zip(chosen, exact, strict=True)) <= 2
    # with true durations (a camera that states them) the choice is FFmpeg's exactly
    assert _on_arrival(pts, tb, 18, durations)[0] == exact


def test_segments_continue_output_indices_and_keep_every_frame_at_fps_0() -> None:
    choice = FrameChoice(None)
    choice.start_segment(Fraction(1, 30))
    first = [c.index for p in range(5) for c in choice.push(p, p + 1)]
    choice.end_segment(5)
    choice.start_segment(Fraction(1, 30))
    second = [c.index for p in range(100, 103) for c in choice.push(p, p + 1)]
    assert first == [0, 1, 2, 3, 4] and second == [5, 6, 7]


# ------------------------------------------------------------------------------------------------- hand-off


def test_drop_oldest_keeps_the_newest_frames() -> None:
    h: FrameHandoff[int] = FrameHandoff(2, "oldest")
    for i in range(5):
        h.put(i)
    assert (h.get(0), h.get(0), h.get(0)) == (3, 4, None)
    assert (h.accepted, h.dropped) == (5, 3)


def test_drop_newest_keeps_the_waiting_frames() -> None:
    h: FrameHandoff[int] = FrameHandoff(2, "newest")
    for i in range(5):
        h.put(i)
    assert (h.get(0), h.get(0)) == (0, 1) and h.dropped == 3


def test_never_waits_for_room_and_cancel_releases_the_producer() -> None:
    h: FrameHandoff[int] = FrameHandoff(1, "never")
    h.put(0)
    done = threading.Event()

    def producer() -> None:
        h.put(1)
        h.put(2)
        done.set()

    t = threading.Thread(target=producer)
    t.start()
    assert not done.wait(0.3)  # blocked: no room
    assert h.get(1) == 0 and h.get(1) == 1
    t.join(2)
    assert done.is_set() and h.dropped == 0
    assert h.get(1) == 2
    h.put(3)
    blocked = threading.Thread(target=h.put, args=(4,))
    blocked.start()
    time.sleep(0.1)
    assert h.cancel() == 1  # 3 was waiting; the producer holding 4 is released, 4 is dropped too
    blocked.join(2)
    assert not blocked.is_alive() and h.dropped == 2
    with pytest.raises(HandoffClosed):
        h.get(0)


def test_handoff_closes_after_draining() -> None:
    h: FrameHandoff[int] = FrameHandoff(3, "oldest")
    h.put(1)
    h.close()
    assert h.get(0) == 1
    with pytest.raises(HandoffClosed):
        h.get(0)


# ------------------------------------------------------------------------------------------------- latency


def test_latency_percentiles_match_numpy_to_a_bin() -> None:
    rng = np.random.default_rng(3)
    values = rng.gamma(2.0, 0.01, 5000)
    stats = LatencyStats()
    for v in values:
        stats.add(float(v))
    for q in (50, 95, 99):
        assert stats.percentile(q) == pytest.approx(np.percentile(values, q, method="inverted_cdf"), abs=1.01e-4)
    assert stats.max_s == values.max() and stats.count == 5000
    stats.add(60.0)  # beyond the histogram: the maximum is still exact
    assert stats.max_s == 60.0 and stats.percentile(100) == 60.0
    assert LatencyStats().percentile(50) is None


# ------------------------------------------------------------------------------------------------- outputs


@needs_ffmpeg
def test_y4m_stream_is_read_by_ffmpeg_frame_for_frame(tmp_path: Path) -> None:
    buf = io.BytesIO()
    pipe = Y4mPipe(buf, Fraction(18))
    for i in range(5):
        pipe.write(i, index_frame(i * 3, 129, 97))  # odd sizes: padded to 130x98
    pipe.close()
    frames = ffmpeg_decoded(buf.getvalue(), "yuv4mpegpipe", 130, 98)
    assert [read_index(f[:97, :129]) for f in frames] == [0, 3, 6, 9, 12]
    assert np.abs(frames[2, :97, :129].astype(int) - index_frame(6, 129, 97)).mean() < 3  # colours survive
    with pytest.raises(InputError, match="y4m stream started at 130x98"):
        pipe.write(5, index_frame(1, 64, 48))


def test_frame_folder_keeps_only_the_newest(tmp_path: Path) -> None:
    folder = FrameFolder(tmp_path / "frames", "jpg", 90, keep=3)
    for i in range(10):
        folder.write(i, index_frame(i, 64, 48))
    folder.close()
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["000007.jpg", "000008.jpg", "000009.jpg"]


# ------------------------------------------------------------------------------------------------- sources


def test_sources_are_classified(tmp_path: Path) -> None:
    clip = tmp_path / "c.mp4"
    clip.write_bytes(b"x")
    assert parse_source("-").kind == "stdin"
    assert parse_source(str(clip)).kind == "file"
    udp = parse_source("udp://127.0.0.1:18499")
    assert udp.kind == "network" and udp.options["overrun_nonfatal"] == "1" and udp.can_reconnect
    assert parse_source("rtsp://127.0.0.1/x").options["rtsp_transport"] == "tcp"
    assert parse_source("rtsp://h/x", options={"rtsp_transport": "udp"}).options["rtsp_transport"] == "udp"
    with pytest.raises(InputError, match=r"^ftp://h/x: unknown stream scheme 'ftp'"):
        parse_source("ftp://h/x")
    with pytest.raises(InputError, match="no such file"):
        parse_source(str(tmp_path / "missing.mp4"))


def test_link_loops_and_frameless_files_are_named_as_such(tmp_path: Path) -> None:
    """A link loop is not "no such file"; FFmpeg's "End of file" of a container without frames says what it means."""
    from colonlight.live.source import open_source

    from ...media import make_clip

    (tmp_path / "a.mp4").symlink_to(tmp_path / "b.mp4")
    (tmp_path / "b.mp4").symlink_to(tmp_path / "a.mp4")
    with pytest.raises(InputError, match=r"a\.mp4: a dangling symbolic link \(or a link loop\)$"):
        parse_source(str(tmp_path / "a.mp4"))
    empty = make_clip(tmp_path / "empty.mkv", 0)  # a Matroska header, no frame
    with pytest.raises(InputError, match=r"empty\.mkv: cannot open \(the source ends before its first video frame\)$"):
        open_source(parse_source(str(empty)), timeout_s=10)


def test_absent_capture_device_is_one_clear_line(tmp_path: Path) -> None:
    absent = Path("/dev/video97")
    if absent.exists():
        pytest.skip("/dev/video97 exists here")
    with pytest.raises(InputError) as err:
        parse_source(str(absent))
    message = str(err.value)
    assert message.startswith("/dev/video97: no such capture device (") and "\n" not in message
    not_device = tmp_path / "video0"
    not_device.write_bytes(b"")
    with pytest.raises(InputError, match="not a capture device"):
        probe_device(not_device)


def test_a_stream_that_never_gave_a_frame_fails_in_the_library_too() -> None:
    """The engine decides it, not the CLI: a UDP listener nothing is sent to, ended by its duration, is an error
    for every caller; stopped by the caller instead, it is not. The duration ends the run even while the source is
    still being opened: a long --timeout does not hold it (the open used to wait the whole timeout)."""
    import socket

    from colonlight.live import LiveStream, StreamOptions
    from colonlight.live.reader import DEADLINE_GRACE_S
    from colonlight.methods import create_method

    src = parse_source(f"udp://127.0.0.1:{free_port(socket.SOCK_DGRAM, range(18700, 18750))}")
    timed = LiveStream(src, create_method("none"), StreamOptions(duration_s=0.5, timeout_s=60.0)).run()
    assert (timed.end, timed.frames_decoded) == ("duration reached", 0)
    assert timed.error == f"{src.text}: no video frame arrived in the 0.5 s duration"
    assert timed.seconds < 0.5 + DEADLINE_GRACE_S + 5.0  # not the 60 s timeout
    stopped = LiveStream(src, create_method("none"), StreamOptions(timeout_s=1.0))
    threading.Timer(0.3, stopped.stop, args=("stopped by the caller",)).start()
    summary = stopped.run()
    assert (summary.end, summary.error) == ("stopped by the caller", None)


@needs_ffmpeg
@pytest.mark.timeout(120)
def test_a_stop_while_a_silent_source_is_read_returns_at_once_and_the_source_is_freed_by_its_timeout(
    tmp_path: Path,
) -> None:
    """A UDP stream (sent by the ffmpeg binary) that delivered frames and went silent: the reader is blocked in a
    read whose timeout (6 s) was fixed when the connection opened. A stop returns the run at once with the summary
    as it stood, long before the duration's end too (600 s, which once stretched the wait); the read, left to time
    out by itself, then frees the listener's port (wait_source_closed)."""
    from colonlight.live import LiveStream, StreamOptions
    from colonlight.methods import create_method

    exe = ffmpeg_exe()
    assert exe is not None
    clip = make_clip(tmp_path / "clip.ts", 30, 30, (128, 96), codec_args=(*X264, "-g", "15"))
    port = free_port(socket.SOCK_DGRAM, range(18750, 18800))
    live = LiveStream(
        parse_source(f"udp://127.0.0.1:{port}"),
        create_method("none"),
        StreamOptions(timeout_s=6.0, duration_s=600.0),
    )
    stopped_at: list[float] = []

    def send_then_stop() -> None:
        time.sleep(0.5)  # the reader listens first
        udp = f"udp://127.0.0.1:{port}?pkt_size=1316"
        subprocess.run([exe, "-v", "error", "-nostdin", "-re", "-i", str(clip), "-c", "copy", "-f", "mpegts", udp])
        time.sleep(0.5)  # silent now, the connection open
        stopped_at.append(time.perf_counter())
        live.stop("stopped by the caller")

    sender = threading.Thread(target=send_then_stop)
    sender.start()
    summary = live.run()
    took = time.perf_counter() - stopped_at[0]
    sender.join()
    assert (summary.end, summary.error) == ("stopped by the caller", None)
    assert summary.frames_decoded > 0 and summary.connections == 1
    assert took < 3.0, took  # not the rest of the 6 s read timeout (the end used to wait for it)
    assert not live.wait_source_closed(0)  # still in its read
    assert live.wait_source_closed(30)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as again:
        again.bind(("127.0.0.1", port))  # the port is free once the source is closed
