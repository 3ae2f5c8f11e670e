"""Load on the HTTP service: N concurrent clients each upload short synthetic clips to a real `colonlight serve`
and poll until their job is finished.

Reported per (clients, clip length): throughput (clips/s, frames/s), p50/p95 latency from the start of the upload
to the job seen finished, 503 retries, and the server's resident memory after start-up and at its peak (VmHWM).
A fresh server is started for every row, so each peak belongs to that row alone; memory must stay flat as the
number of clients and the clip length grow (uploads are streamed to disk, frames stream through bounded queues).

    python -m benchmarks.service_load [--clients 1,4,8] [--seconds 2,6] [--clips-per-client 1] [--workers 2]
                                      [--method rnn] [--size 320x240]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from .common import REPO, markdown_table


def synthetic_clip(
    path: Path, seconds: float, fps: float = 25.0, size: tuple[int, int] = (320, 240), seed: int = 0
) -> Path:
    """A moving, flickering gradient, written with the engine's H.264 writer."""
    from colonlight.video import VideoWriter

    w, h = size
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    base = (x / w * 180 + y / h * 60)[..., None] * np.array([1.0, 0.55, 0.5], np.float32)
    with VideoWriter(path, fps=fps, preset="ultrafast") as writer:
        for i in range(round(seconds * fps)):
            gain = 0.45 + 0.4 * np.sin(i / 9.0) ** 2
            frame = np.roll(base, i * 3, axis=1) * gain + rng.normal(0, 4, (h, w, 1)).astype(np.float32)
            writer.write(np.clip(frame, 0, 255).astype(np.uint8))
    return path


def weights_for_benchmark(tmp: Path, method: str) -> tuple[dict[str, str], str]:
    """The shipped model when present; else freshly initialised weights (same cost per frame)."""
    if method != "rnn":
        return {}, method
    from colonlight.checkpoint import DEFAULT_WEIGHTS, save_weights
    from colonlight.model import GammaNet

    if DEFAULT_WEIGHTS.is_file():
        return {}, f"rnn ({DEFAULT_WEIGHTS.stem})"
    path = tmp / "bench.safetensors"
    save_weights(GammaNet().eval(), path, {"name": "bench-random", "input_size": 64})
    return {"COLONLIGHT_WEIGHTS": str(path)}, "rnn (random weights: the default model is not installed)"


def run_clients(url: str, clip: Path, n_clients: int, per_client: int) -> tuple[list[float], int, int, int]:
    """(latencies, frames, failures, retries) of n_clients clients, each submitting per_client clips in turn."""
    latencies: list[float] = []
    frames = failures = retries = 0
    lock = threading.Lock()
    payload = clip.read_bytes()
    barrier = threading.Barrier(n_clients)

    def client() -> None:
        nonlocal frames, failures, retries
        with httpx.Client(base_url=url, timeout=120) as c:
            barrier.wait()
            for _ in range(per_client):
                t0 = time.perf_counter()
                while True:
                    r = c.post("/v1/jobs", files={"file": (clip.name, payload, "video/mp4")})
                    if r.status_code != 503:
                        break
                    with lock:
                        retries += 1
                    time.sleep(min(1.0, float(r.headers.get("retry-after", "1"))))
                if r.status_code != 202:
                    with lock:
                        failures += 1
                    continue
                loc = r.headers["location"]
                while (job := c.get(loc).json())["status"] not in ("succeeded", "failed"):
                    time.sleep(0.05)
                elapsed = time.perf_counter() - t0
                with lock:
                    if job["status"] == "succeeded":
                        latencies.append(elapsed)
                        frames += job["frames_done"]
                    else:
                        failures += 1
                c.delete(loc)

    threads = [threading.Thread(target=client) for _ in range(n_clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return latencies, frames, failures, retries


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    if len(values) == 1:
        return values[0]
    return statistics.quantiles(values, n=100, method="inclusive")[int(q) - 1]


def main(argv: list[str] | None = None) -> str:
    sys.path.insert(0, str(REPO))
    from tests.service_server import ServiceServer

    ap = argparse.ArgumentParser(prog="python -m benchmarks.service_load")
    ap.add_argument("--clients", default="1,4,8", help="comma-separated numbers of concurrent clients")
    ap.add_argument("--seconds", default="2,6", help="comma-separated clip lengths in seconds (25 fps sources)")
    ap.add_argument("--clips-per-client", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--method", default="rnn")
    ap.add_argument("--size", default="320x240")
    args = ap.parse_args(argv or [])
    clients = [int(v) for v in args.clients.split(",")]
    lengths = [float(v) for v in args.seconds.split(",")]
    size = tuple(int(v) for v in args.size.split("x"))

    rows = []
    with tempfile.TemporaryDirectory(prefix="colonlight-load-") as tmp_name:
        tmp = Path(tmp_name)
        env, label = weights_for_benchmark(tmp, args.method)
        env.update(
            {
                "COLONLIGHT_METHOD": args.method,
                "COLONLIGHT_WORKERS": str(args.workers),
                "COLONLIGHT_QUEUE_SIZE": str(max(clients) + 4),
            }
        )
        for seconds in lengths:
            clip = synthetic_clip(tmp / f"clip-{seconds:g}s.mp4", seconds, size=size)  # type: ignore[arg-type]
            for n in clients:
                data = tmp / f"data-{seconds:g}-{n}"
                with ServiceServer(data, env) as srv:
                    start_rss = srv.peak_rss_bytes() or 0
                    t0 = time.perf_counter()
                    lat, frames, failed, retries = run_clients(srv.url, clip, n, args.clips_per_client)
                    wall = time.perf_counter() - t0
                    peak = srv.peak_rss_bytes() or 0
                done = len(lat)
                rows.append(
                    [
                        n,
                        f"{seconds:g} s ({clip.stat().st_size // 1024} KiB)",
                        done,
                        failed,
                        retries,
                        f"{done / wall:.2f}",
                        f"{frames / wall:.1f}",
                        f"{percentile(lat, 50):.2f}",
                        f"{percentile(lat, 95):.2f}",
                        f"{start_rss / 2**20:.0f}",
                        f"{peak / 2**20:.0f}",
                    ]
                )
    head = [
        "## Service load (`python -m benchmarks.service_load`)",
        "",
        (
            f"Real `colonlight serve` on loopback, {args.workers} workers, method {label}, {size[0]}x{size[1]} "
            "clips at "
            f"25 fps, extracted at 18 fps, frames + video written; {args.clips_per_client} clip(s) per client, "
            "latency = upload start to job seen finished (polling every 50 ms); a fresh server per row."
        ),
        "",
    ]
    table = markdown_table(
        [
            "clients",
            "clip",
            "clips done",
            "failed",
            "503 retries",
            "clips/s",
            "frames/s",
            "p50 latency s",
            "p95 latency s",
            "RSS after start MiB",
            "peak RSS MiB",
        ],
        rows,
    )
    return "\n".join(head) + "\n" + table


if __name__ == "__main__":
    print(main(sys.argv[1:]))
