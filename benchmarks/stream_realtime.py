"""`colonlight stream` on a live 1080p30 H.264 feed at 18 fps: latency, drops, memory over time.

The feed: a 10-second 1920x1080 synthetic colonoscopy clip (H.264, a keyframe a second, as a live encoder sends),
looped by the ffmpeg binary of imageio-ffmpeg and played in real time (`-re -stream_loop -1 ... -c copy -f mpegts`)
into `colonlight stream -`, which writes `gammas.jsonl` and a y4m stream (to /dev/null: the consumer is not what is
measured), and in a second configuration also JPEG frames with `--keep 100`. ffmpeg starts only once colonlight is
waiting for frames, so the model load is not in the numbers.

Reported from colonlight's own records (`stream.json`, `gammas.jsonl`): frames in/out/dropped, latency from a
frame's arrival (out of the decoder) to its output (written to every output) as p50/p95/max, the same after the
first 5 seconds, and colonlight's resident memory sampled every second (at 10% of the run, at the end, its slope).

    python -m benchmarks stream                 # the short version: 60 s per configuration
    python -m benchmarks stream --seconds 20    # shorter still
    python -m benchmarks stream --long          # the full check: 30 minutes per configuration
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

from colonlight.limits import available_cores

from .common import encode_synthetic_clip, ffmpeg_exe, markdown_table

SRC_FPS = 30
LONG_SECONDS = 1800
SHORT_SECONDS = 60
WARMUP_S = 5.0


def make_feed(path: Path, width: int, height: int, seconds: float = 10.0) -> Path:
    """A synthetic clip rendered at a quarter of the size (60 frames, played back and forth) and upscaled."""
    quarter = (max(32, width // 4 // 2 * 2), max(24, height // 4 // 2 * 2))
    return encode_synthetic_clip(
        path,
        seed=11,
        render_size=quarter,
        size=(width, height),
        fps=SRC_FPS,
        rendered=60,
        frames=int(seconds * SRC_FPS),
        crf=20,
        gop=SRC_FPS,
    )


def _rss_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def _cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of ``pid`` (all threads) so far."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_stream(feed: Path, out: Path, seconds: float, extra: list[str]) -> dict:
    """One live run; returns colonlight's summary plus the memory samples."""
    colonlight = Path(sys.executable).parent / "colonlight"
    cmd = [
        str(colonlight) if colonlight.exists() else sys.executable,
        *([] if colonlight.exists() else ["-m", "colonlight_cli.main"]),
    ]
    cmd += ["stream", "-", "-o", str(out), "--pipe", "y4m", *extra]
    r, w = os.pipe()
    with open(os.devnull, "wb") as sink:
        proc = subprocess.Popen(cmd, stdin=r, stdout=sink, stderr=subprocess.PIPE)
    os.close(r)
    assert proc.stderr is not None
    ready = threading.Event()
    log: list[str] = []

    def pump() -> None:
        assert proc.stderr is not None
        for line in iter(proc.stderr.readline, b""):
            log.append(line.decode(errors="replace"))
            if "waiting for frames" in log[-1]:
                ready.set()

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    if not ready.wait(300):
        proc.kill()
        raise RuntimeError("colonlight stream did not start:\n" + "".join(log))
    feeder = subprocess.Popen(
        [
            ffmpeg_exe(),
            "-hide_banner",
            "-loglevel",
            "error",
            "-nostdin",
            "-re",
            "-stream_loop",
            "-1",
            "-i",
            str(feed),
            "-t",
            str(seconds),
            "-c",
            "copy",
            "-f",
            "mpegts",
            "-",
        ],
        stdout=w,
    )
    os.close(w)
    t0 = time.perf_counter()
    rss: list[tuple[float, float]] = []
    cpu: list[tuple[float, float]] = []  # (seconds since the feed started, colonlight's CPU seconds)
    load = [os.getloadavg()[0]]
    while proc.poll() is None:
        value, used = _rss_mib(proc.pid), _cpu_s(proc.pid)
        if value is not None and used is not None:
            rss.append((time.perf_counter() - t0, value))
            cpu.append((time.perf_counter() - t0, used))
        time.sleep(1.0)
        if len(rss) % 30 == 0:
            load.append(os.getloadavg()[0])
    feeder.wait()
    reader.join(10)
    if proc.returncode != 0:
        raise RuntimeError(f"colonlight stream failed ({proc.returncode}):\n" + "".join(log[-20:]))
    summary = json.loads((out / "stream.json").read_text())["summary"]
    records = [json.loads(line) for line in (out / "gammas.jsonl").read_text().splitlines()]
    return {"summary": summary, "records": records, "rss": rss, "cpu": cpu, "load": load}


def drop_times(result: dict) -> list[float]:
    """Seconds into the stream (from the first output frame's arrival) of every missing output index, so a drop
    can be told apart as a start-up, a mid-stream stall or the end."""
    records = result["records"]
    if not records:
        return []
    t0 = records[0]["arrival"]
    times: list[float] = [0.0] * records[0]["index"]
    for prev, cur in zip(records, records[1:], strict=False):
        times += [round(cur["arrival"] - t0, 1)] * (cur["index"] - prev["index"] - 1)
    missing_at_end = result["summary"]["frames_in"] - (records[-1]["index"] + 1)
    times += [round(records[-1]["arrival"] - t0, 1)] * max(0, missing_at_end)
    return times


def _row(label: str, result: dict) -> list[object]:
    s, records, rss = result["summary"], result["records"], result["rss"]
    lat = np.array([r["latency_ms"] for r in records])
    t0 = records[0]["arrival"] if records else 0.0
    steady = np.array([r["latency_ms"] for r in records if r["arrival"] - t0 >= WARMUP_S])
    start_idx = [r["index"] for r in records if r["arrival"] - t0 >= WARMUP_S]
    steady_drops = (start_idx[-1] - start_idx[0] + 1 - len(start_idx)) if start_idx else 0
    values = np.array([v for _, v in rss])
    times = np.array([t for t, _ in rss])
    tenth = values[len(values) // 10] if len(values) else float("nan")
    half = len(values) // 2
    slope = np.polyfit(times[half:], values[half:], 1)[0] * 600 if len(values) - half >= 3 else float("nan")

    def p(a: np.ndarray, q: float) -> str:
        return f"{np.percentile(a, q):.1f}" if len(a) else "-"

    cpu = result["cpu"]
    # CPU share while streaming (between the first and the last sample: the model load before the feed is excluded)
    share = (
        (cpu[-1][1] - cpu[0][1]) / (cpu[-1][0] - cpu[0][0])
        if len(cpu) >= 2 and cpu[-1][0] > cpu[0][0]
        else float("nan")
    )
    return [
        label,
        f"{s['seconds']:.0f}",
        s["frames_in"],
        s["frames_out"],
        s["frames_dropped"],
        steady_drops,
        p(lat, 50),
        p(lat, 95),
        f"{lat.max():.1f}" if len(lat) else "-",
        p(steady, 95),
        f"{tenth:.0f}",
        f"{values[-1]:.0f}" if len(values) else "-",
        f"{values.max():.0f}" if len(values) else "-",
        f"{slope:+.1f}",
        f"{s.get('behind_max_s', 0.0):.2f}",
        f"{100 * share:.0f}%",
        f"{min(result['load']):.1f}-{max(result['load']):.1f}",
    ]


def stage_costs(feed: Path, frames: int = 90) -> list[list[object]]:
    """CPU milliseconds per frame of each stage, as `colonlight stream` runs it, one stage at a time in this process
    (process CPU time, so a busy machine slows the wall clock but hardly these numbers)."""
    import av
    import torch
    from av.video.reformatter import VideoReformatter

    from colonlight.frames import encode_image
    from colonlight.live.outputs import Y4mPipe
    from colonlight.methods import create_method

    torch.set_num_threads(1)
    with av.open(str(feed)) as container:
        stream = container.streams.video[0]
        stream.codec_context.thread_type = "SLICE"
        t = time.process_time()
        decoded = []
        for frame in container.decode(stream):
            decoded.append(frame)
            if len(decoded) == frames:
                break
        decode = (time.process_time() - t) / len(decoded)
    reformatter = VideoReformatter()
    t = time.process_time()
    rgb = [reformatter.reformat(f, format="rgb24").to_ndarray() for f in decoded]
    convert = (time.process_time() - t) / len(rgb)
    method_stream = create_method("rnn", device="cpu").stream()
    method_stream.push(rgb[0])
    t = time.process_time()
    enhanced = [r.frame for f in rgb for r in method_stream.push(f)]
    enhance = (time.process_time() - t) / len(rgb)
    with open(os.devnull, "wb") as sink:
        pipe = Y4mPipe(sink, Fraction(18))
        t = time.process_time()
        for i, f in enumerate(enhanced):
            pipe.write(i, f)
        y4m = (time.process_time() - t) / len(enhanced)
    t = time.process_time()
    for f in enhanced[:30]:
        encode_image(f, "jpg", 95)
    jpeg = (time.process_time() - t) / 30
    rate_out = 18
    rows = [
        ["decode (every source frame)", f"{1000 * decode:.1f}", SRC_FPS, f"{100 * decode * SRC_FPS:.0f}%"],
        ["to RGB (chosen frames)", f"{1000 * convert:.1f}", rate_out, f"{100 * convert * rate_out:.0f}%"],
        [
            "enhance: resize + network + gamma LUT",
            f"{1000 * enhance:.1f}",
            rate_out,
            f"{100 * enhance * rate_out:.0f}%",
        ],
        ["y4m: to YUV 4:2:0 + write", f"{1000 * y4m:.1f}", rate_out, f"{100 * y4m * rate_out:.0f}%"],
        ["JPEG q95 (with --format jpg)", f"{1000 * jpeg:.1f}", rate_out, f"{100 * jpeg * rate_out:.0f}%"],
    ]
    main_loop = enhance + y4m
    rows.append(["processing loop per frame (enhance + y4m)", f"{1000 * main_loop:.1f}", "", ""])
    return rows


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m benchmarks stream", description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=SHORT_SECONDS, help="length of each live run")
    parser.add_argument("--long", action="store_true", help=f"{LONG_SECONDS // 60}-minute runs (the full check)")
    parser.add_argument("--size", default="1920x1080", help="feed size WxH")
    parser.add_argument(
        "--configs",
        default="log+pipe,log+pipe+jpg",
        help="comma-separated: log+pipe, log+pipe+jpg, log+pipe-whole (log+pipe with --content full: the baseline "
        "for the content area's cost)",
    )
    args = parser.parse_args(argv or [])
    seconds = LONG_SECONDS if args.long else args.seconds
    width, height = (int(v) for v in args.size.lower().split("x"))
    configs = {
        "log+pipe": ["--no-frames"],
        "log+pipe+jpg": ["--format", "jpg", "--keep", "100"],
        "log+pipe-whole": ["--no-frames", "--content", "full"],
    }
    rows = []
    drops: list[str] = []
    with tempfile.TemporaryDirectory(prefix="colonlight-bench-stream-") as tmp:
        work = Path(tmp)
        cache = Path(os.environ.get("COLONLIGHT_BENCH_CACHE", "") or work)
        cache.mkdir(parents=True, exist_ok=True)
        feed = cache / f"feed-{width}x{height}-10s.mp4"
        if not feed.is_file():
            with tempfile.TemporaryDirectory(dir=cache) as part:
                os.replace(make_feed(Path(part) / feed.name, width, height), feed)
        costs = stage_costs(feed)
        for name in args.configs.split(","):
            result = run_stream(feed, work / name, seconds, configs[name])
            rows.append(_row(name, result))
            at = drop_times(result)
            drops.append(f"{name}: " + (", ".join(f"{t:g} s" for t in at) if at else "none"))
    return "\n".join(
        [
            f"## colonlight stream: {width}x{height} H.264 at {SRC_FPS} fps played live into `colonlight stream -` "
            "at 18 fps",
            "",
            markdown_table(
                [
                    "outputs",
                    "s",
                    "in",
                    "out",
                    "dropped",
                    f"dropped after {WARMUP_S:g} s",
                    "p50 ms",
                    "p95 ms",
                    "max ms",
                    f"p95 after {WARMUP_S:g} s",
                    "RSS MiB at 10%",
                    "RSS at end",
                    "RSS max",
                    "RSS slope MiB/10 min (2nd half)",
                    "decoder behind live, max s",
                    "CPU (of one core)",
                    "load avg",
                ],
                rows,
            ),
            "",
            "targets: p95 <= 50 ms and no drops on a quiet machine; memory flat.",
            "",
            "drops, seconds into the stream: " + "; ".join(drops) + ".",
            "",
            f"### CPU cost per frame, {width}x{height} (process CPU time, one stage at a time)",
            "",
            markdown_table(["stage", "CPU ms/frame", "frames/s", "share of one core"], costs),
            "",
            "Latency on a machine with a core to spare is about the processing loop's time per frame. "
            f"{available_cores()} cores; load average (1 / 5 / 15 min) at the end: "
            + " / ".join(f"{x:.1f}" for x in os.getloadavg())
            + ".",
        ]
    )


if __name__ == "__main__":
    print(main(sys.argv[1:]))
