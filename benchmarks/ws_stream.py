"""Frames per second of the WebSocket route (`/v1/stream`) for 1, 2 and 4 clients at once.

Each client streams JPEG frames to a real `colonlight serve` on loopback the way the web page does: one frame in
flight (it sends the next when the enhanced frame is back), JPEG answers. Reported per number of clients: frames
per second in all and per client, the client's round trip p50/p95 (send to enhanced frame received), the server's
own latency p50 (frame received to answer sent, from the records), the server's CPU time per frame (decode,
network, LUT, encode, WebSocket; what bounds frames/s on a machine with nothing else to do: cores x 1000 / it), and
the server's peak resident memory. A fresh
server per row, so each peak belongs to that row alone; the first frames of each client are a warm-up.

    python -m benchmarks ws_stream [--clients 1,2,4] [--frames 150] [--size 640x480] [--depth 1]
                                   [--torch-threads N] [--method rnn]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from colonlight.limits import available_cores

from .common import REPO, markdown_table
from .service_load import percentile, weights_for_benchmark

WARMUP_FRAMES = 5


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (all its threads), from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def jpeg_frames(size: tuple[int, int], n: int = 24, seed: int = 0) -> list[bytes]:
    """``n`` JPEGs (quality 90) of a dark tunnel whose light swings, with sensor noise: what a scope sends."""
    w, h = size
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    out = []
    for i in range(n):
        r = np.hypot(x - w / 2, y - h / 2) / (0.5 * np.hypot(w, h))
        lum = np.clip(r * 1.6, 0, 1) * (0.45 + 0.35 * np.sin(i / 4)) * (0.8 + 0.2 * np.sin(r * 40 - i))
        rgb = lum[..., None] * np.array([110, 130, 230], np.float32) + rng.normal(0, 3, (h, w, 1))  # BGR
        out.append(
            bytes(cv2.imencode(".jpg", np.clip(rgb, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90])[1])
        )
    return out


def run_clients(
    url: str,
    frames: list[bytes],
    n_clients: int,
    per_client: int,
    depth: int,
) -> tuple[float, int, list[float], list[float], int]:
    """(wall s, frames answered, round trips s, server latencies ms, errors) of ``n_clients`` streaming at once."""
    from websockets.sync.client import connect

    rtts: list[float] = []
    server_ms: list[float] = []
    answered = errors = 0
    lock = threading.Lock()
    ready = threading.Barrier(n_clients + 1)
    done = threading.Barrier(n_clients + 1)

    def client(seed: int) -> None:
        nonlocal answered, errors
        with connect(url, proxy=None, max_size=None, compression=None, open_timeout=60) as ws:
            ws.send(json.dumps({"type": "start", "format": "jpeg", "quality": 90}))
            assert json.loads(ws.recv(60))["type"] == "ready"
            sent_at: list[float] = []

            def send(i: int) -> None:
                sent_at.append(time.perf_counter())
                ws.send(frames[(i + seed) % len(frames)])

            def receive(i: int, mine: list[float], ms: list[float]) -> None:
                record = json.loads(ws.recv(120))
                if record["type"] != "result":
                    raise RuntimeError(f"unexpected answer: {record}")
                ws.recv(120)  # the enhanced JPEG
                if i >= WARMUP_FRAMES:
                    mine.append(time.perf_counter() - sent_at[i])
                    ms.append(record["latency_ms"])

            for i in range(WARMUP_FRAMES):
                send(i)
                receive(i, [], [])
            ready.wait()
            mine: list[float] = []
            ms: list[float] = []
            total = WARMUP_FRAMES + per_client
            nxt = WARMUP_FRAMES
            for i in range(WARMUP_FRAMES, total):  # keep `depth` frames in flight
                while nxt < total and nxt - i < depth:
                    send(nxt)
                    nxt += 1
                receive(i, mine, ms)
            done.wait()
            ws.send(json.dumps({"type": "end"}))
            with lock:
                rtts.extend(mine)
                server_ms.extend(ms)
                answered += len(mine)

    def guarded(seed: int) -> None:
        nonlocal errors
        try:
            client(seed)
        except Exception as exc:  # noqa: BLE001 - counted and reported, the other clients go on
            with lock:
                errors += 1
            print(f"client {seed}: {type(exc).__name__}: {exc}", file=sys.stderr)
            for barrier in (ready, done):
                barrier.abort()

    threads = [threading.Thread(target=guarded, args=(7 * k,)) for k in range(n_clients)]
    for t in threads:
        t.start()
    t0 = time.perf_counter()
    try:
        ready.wait()
        t0 = time.perf_counter()
        done.wait()
    except threading.BrokenBarrierError:
        pass  # a client failed: reported in the errors column
    wall = time.perf_counter() - t0
    for t in threads:
        t.join()
    return wall, answered, rtts, server_ms, errors


def main(argv: list[str] | None = None) -> str:
    sys.path.insert(0, str(REPO))
    from tests.service_server import ServiceServer

    ap = argparse.ArgumentParser(prog="python -m benchmarks ws_stream")
    ap.add_argument("--clients", default="1,2,4", help="comma-separated numbers of clients streaming at once")
    ap.add_argument("--frames", type=int, default=150, help="timed frames per client (after 5 warm-up frames)")
    ap.add_argument("--size", default="640x480", help="frame size WxH")
    ap.add_argument("--depth", type=int, default=1, help="frames in flight per client (1: as the web page)")
    ap.add_argument("--torch-threads", type=int, default=None, help="COLONLIGHT_TORCH_THREADS (default: the server's)")
    ap.add_argument("--method", default="rnn")
    args = ap.parse_args(argv or [])
    clients = [int(v) for v in args.clients.split(",")]
    w, h = (int(v) for v in args.size.split("x"))
    frames = jpeg_frames((w, h))

    rows = []
    with tempfile.TemporaryDirectory(prefix="colonlight-ws-") as tmp_name:
        tmp = Path(tmp_name)
        env, label = weights_for_benchmark(tmp, args.method)
        env.update({"COLONLIGHT_METHOD": args.method, "COLONLIGHT_STREAM_MAX": str(max(clients))})
        if args.torch_threads:
            env["COLONLIGHT_TORCH_THREADS"] = str(args.torch_threads)
        for n in clients:
            load0 = os.getloadavg()[0]
            srv = ServiceServer(tmp / f"data-{n}", env).start(timeout=300)  # a busy machine loads torch slowly
            try:
                start_rss = srv.peak_rss_bytes() or 0
                url = srv.url.replace("http://", "ws://") + "/v1/stream"
                assert srv.proc is not None
                cpu0 = cpu_seconds(srv.proc.pid)
                wall, answered, rtts, server_ms, errors = run_clients(url, frames, n, args.frames, args.depth)
                cpu_ms = (cpu_seconds(srv.proc.pid) - cpu0) * 1000 / max(1, n * (args.frames + WARMUP_FRAMES))
                peak = srv.peak_rss_bytes() or 0
            finally:
                srv.stop()
            load1 = os.getloadavg()[0]
            fps = answered / wall if wall > 0 else float("nan")
            rows.append(
                [
                    n,
                    answered,
                    errors,
                    f"{fps:.1f}",
                    f"{fps / n:.1f}",
                    f"{percentile(rtts, 50) * 1000:.0f}",
                    f"{percentile(rtts, 95) * 1000:.0f}",
                    f"{statistics.median(server_ms) if server_ms else float('nan'):.0f}",
                    f"{cpu_ms:.1f}",
                    f"{start_rss / 2**20:.0f}",
                    f"{peak / 2**20:.0f}",
                    f"{load0:.1f}-{load1:.1f}",
                ]
            )
    head = [
        "## WebSocket route (`python -m benchmarks ws_stream`)",
        "",
        (
            f"Real `colonlight serve` on loopback, method {label}, {w}x{h} JPEG frames (quality 90) in and out, "
            f"{args.depth} frame(s) in flight per client, {args.frames} timed frames per client after "
            f"{WARMUP_FRAMES} warm-up frames; a fresh server per row; {available_cores()} cores."
        ),
        "",
    ]
    table = markdown_table(
        [
            "clients",
            "frames",
            "client errors",
            "frames/s (all)",
            "frames/s per client",
            "round trip p50 ms",
            "round trip p95 ms",
            "server latency p50 ms",
            "server CPU ms/frame",
            "RSS after start MiB",
            "peak RSS MiB",
            "load avg (1 min)",
        ],
        rows,
    )
    return "\n".join(head) + "\n" + table


if __name__ == "__main__":
    print(main(sys.argv[1:]))
