"""`colonlight enhance` against FFmpeg doing the same extraction, side by side in one run.

The clip: 20 s of 1350x1080 H.264 at 30 fps, rendered by colonlight's generator (so PNG sizes are realistic).
Baseline: the `ffmpeg` binary shipped by imageio-ffmpeg running `fps=18` plus a gamma lookup table (`lutrgb`) and
writing the same frame format. Each command runs `REPEATS` times, alternating; medians of wall time (and of CPU time
summed over threads, steadier on a shared machine) and the ratio of the wall medians are printed.

JPEG settings are matched, not just the format: colonlight writes 4:2:0 JPEGs at quality 95 (OpenCV/libjpeg-turbo).
`lutrgb` hands the encoder RGB, from which FFmpeg's mjpeg picks 4:4:4 unless told otherwise, and `-q:v 2` at 4:2:0
is coarser than quality 95 (on this clip: 37.8 dB and 164 kB a frame against our 39.2 dB and 334 kB, same gamma).
`-pix_fmt yuvj420p -qmin 1 -q:v 1` matches ours (4:2:0, 39.1 dB, 314 kB) and costs FFmpeg about the CPU time of
the 4:4:4 `-q:v 2` it would otherwise write.
Also: the model's own cost per frame at the default input size and at full resolution, and peak memory (max RSS)
of `colonlight enhance` on a 10-second and a 10-minute clip.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from colonlight.limits import available_cores

from .common import encode_synthetic_clip, ffmpeg_exe, markdown_table

REPEATS = int(os.environ.get("COLONLIGHT_BENCH_REPEATS", "3"))
WIDTH, HEIGHT, SRC_FPS = 1350, 1080, 30
GAMMA = 0.8  # the baseline's table; colonlight's gamma varies per frame, the cost of a table does not


def colonlight_cmd() -> list[str]:
    exe = Path(sys.executable).parent / "colonlight"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "colonlight_cli.main"]


def make_clip(path: Path, seconds: float, width: int, height: int, fps: int = SRC_FPS) -> Path:
    """A synthetic colonoscopy clip: rendered at a quarter of the size, upscaled by FFmpeg, H.264 crf 18; longer
    clips loop the rendered frames back and forth."""
    n = int(round(seconds * fps))
    quarter = (width // 2 // 2 * 2, height // 2 // 2 * 2)
    return encode_synthetic_clip(
        path, seed=7, render_size=quarter, size=(width, height), fps=fps, rendered=min(n, 300), frames=n, crf=18
    )


def timed(cmd: list[str]) -> tuple[float, int, float]:
    """Wall seconds, peak RSS (KiB) and CPU seconds (user + system, all threads) of one command, run in a fresh
    child process."""
    wrapper = (
        "import resource,subprocess,sys,time;t=time.perf_counter();r=subprocess.run(sys.argv[1:],"
        "stdout=subprocess.DEVNULL,stderr=subprocess.PIPE);e=time.perf_counter()-t;"
        "sys.stderr.write(r.stderr.decode()[-2000:]) if r.returncode else None;"
        "u=resource.getrusage(resource.RUSAGE_CHILDREN);"
        "print(e, u.ru_maxrss, u.ru_utime + u.ru_stime, r.returncode)"
    )
    out = subprocess.run([sys.executable, "-c", wrapper, *cmd], capture_output=True, text=True, check=True)
    seconds, rss, cpu, code = out.stdout.split()
    if code != "0":
        raise RuntimeError(f"{' '.join(cmd)} failed: {out.stderr}")
    return float(seconds), int(rss), float(cpu)


def ffmpeg_cmd(clip: Path, out: Path, fmt: str) -> list[str]:
    curve = f"255*pow(val/255\\,{GAMMA})"
    quality = ["-pix_fmt", "yuvj420p", "-qmin", "1", "-q:v", "1"] if fmt == "jpg" else []  # = ours: see above
    return [
        ffmpeg_exe(),
        "-hide_banner",
        "-loglevel",
        "error",
        "-y",
        "-i",
        str(clip),
        "-vf",
        f"fps=18,lutrgb=r='{curve}':g='{curve}':b='{curve}'",
        *quality,
        str(out / f"%06d.{fmt}"),
    ]


def compare_formats(work: Path, clip: Path, formats: tuple[str, ...] = ("png", "jpg")) -> list[list[object]]:
    rows = []
    for fmt in formats:
        ours: list[tuple[float, int, float]] = []
        theirs: list[tuple[float, int, float]] = []
        load: list[float] = []  # 1-minute load average before each run: the machine is shared
        for r in range(REPEATS):
            for who in ("ffmpeg", "colonlight") if r % 2 == 0 else ("colonlight", "ffmpeg"):
                out = work / f"{who}-{fmt}"
                shutil.rmtree(out, ignore_errors=True)
                out.mkdir()
                load.append(os.getloadavg()[0])
                if who == "ffmpeg":
                    theirs.append(timed(ffmpeg_cmd(clip, out, fmt)))
                else:
                    ours.append(timed([*colonlight_cmd(), "enhance", str(clip), "-o", str(out), "--format", fmt, "-q"]))
        n_ours = len(list((work / f"colonlight-{fmt}").rglob(f"*.{fmt}")))
        n_theirs = len(list((work / f"ffmpeg-{fmt}").glob(f"*.{fmt}")))
        mo, mt = statistics.median(t[0] for t in ours), statistics.median(t[0] for t in theirs)
        co, ct = statistics.median(t[2] for t in ours), statistics.median(t[2] for t in theirs)
        target = 1.0 if fmt == "png" else 1.3
        rows.append(
            [
                fmt,
                n_ours,
                n_theirs,
                f"{mt:.2f}",
                f"{mo:.2f}",
                f"{ct:.1f}",
                f"{co:.1f}",
                f"{mo / mt:.2f}x",
                f"<= {target}x",
                "yes" if mo / mt <= target else "NO",
                f"{min(load):.1f}-{max(load):.1f}",
            ]
        )
    return rows


def model_cost() -> list[list[object]]:
    """ms per frame of the network as `colonlight enhance` runs it: the stream's own step (resize to the network
    input, tensor, one recurrent step) with the torch thread count the CLI sets for that input size (one thread at
    the default size: a second OpenMP thread barely helps such a small step, and on a busy machine it waits for a
    core)."""
    import torch

    from colonlight.batch import MethodSpec, network_threads
    from colonlight.checkpoint import load_weights
    from colonlight.methods.rnn import DEFAULT_MODEL_SIZE, RecurrentGammaMethod, network_input

    from .common import median_time

    weights = load_weights(None)
    frame = np.random.default_rng(0).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    rows = []
    for label, size, reps in (
        (f"default ({DEFAULT_MODEL_SIZE}x{DEFAULT_MODEL_SIZE})", DEFAULT_MODEL_SIZE, 50),
        (f"full resolution ({WIDTH}x{HEIGHT}, the release)", None, 3),
    ):
        threads = network_threads(MethodSpec.of("rnn", model_size=size if size else "full"), 1)
        torch.set_num_threads(threads)
        stream = RecurrentGammaMethod(weights, model_size=size if size else "full", device="cpu").stream()
        step = median_time(lambda s=stream: s.predict_a(frame), repeats=reps, warmup=2)
        resize = median_time(lambda n=size: network_input(frame, n), repeats=reps, warmup=2) if size else 0.0
        rows.append([label, threads, f"{1000 * step:.1f}", f"{1000 * resize:.1f}" if size else "-"])
    return rows


def memory(work: Path) -> list[list[object]]:
    rows = []
    for label, seconds in (("10 s", 10), ("10 min", 600)):
        clip = make_clip(work / f"mem-{seconds}.mp4", seconds, 320, 256)
        out = work / f"mem-out-{seconds}"
        t, rss, _ = timed([*colonlight_cmd(), "enhance", str(clip), "-o", str(out), "-q"])
        frames = json.loads((out / clip.stem / "gammas.json").read_text())["frame_count"]
        rows.append([label, frames, f"{t:.1f}", f"{rss / 1024:.0f}"])
        shutil.rmtree(out)
    return rows


def main() -> str:
    with tempfile.TemporaryDirectory(prefix="colonlight-bench-") as tmp:
        work = Path(tmp)
        t0 = time.perf_counter()
        # COLONLIGHT_BENCH_CACHE=DIR keeps the 20 s clip (3 minutes to make) in DIR for the next run
        cache = Path(os.environ.get("COLONLIGHT_BENCH_CACHE", "") or work)
        cache.mkdir(parents=True, exist_ok=True)
        clip = cache / f"clip-{WIDTH}x{HEIGHT}-20s.mp4"
        if not clip.is_file():
            with tempfile.TemporaryDirectory(dir=cache) as part:
                os.replace(make_clip(Path(part) / clip.name, 20, WIDTH, HEIGHT), clip)
        sys.stderr.write(f"benchmark clip ready in {time.perf_counter() - t0:.0f} s\n")
        speed = compare_formats(work, clip)
        cost = model_cost()
        mem = memory(work)
    load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
    return "\n".join(
        [
            f"## colonlight enhance vs FFmpeg (20 s 1350x1080 H.264 at 30 fps -> 18 fps frames; median of {REPEATS})",
            "",
            markdown_table(
                [
                    "format",
                    "frames (ours)",
                    "frames (ffmpeg)",
                    "ffmpeg s",
                    "colonlight s",
                    "ffmpeg CPU s",
                    "colonlight CPU s",
                    "ratio (wall)",
                    "target",
                    "met",
                    "load avg (1 min)",
                ],
                speed,
            ),
            "",
            "## Model cost per frame (network step incl. resize, 1350x1080 input)",
            "",
            markdown_table(
                ["network input", "torch threads (as the CLI)", "ms/frame (median)", "of which resize ms"], cost
            ),
            "",
            "## Peak memory of `colonlight enhance` (320x256 clips at 30 fps, PNG frames)",
            "",
            markdown_table(["clip", "frames", "seconds", "max RSS MiB"], mem),
            "",
            f"{available_cores()} cores; load average at the end (1 / 5 / 15 min): {load}.",
        ]
    )


if __name__ == "__main__":
    print(main())
