"""Test fixtures: real, small video files and image folders, made on the fly.

Every generated frame carries its own index, drawn as a 4x4 grid of dark/bright cells (16 bits, least
significant bit top-left) that survives H.264 compression and scaling; :func:`read_index` reads it back. So a
test can ask "which source frame is this?" of any decoder's output, ours or the ``ffmpeg`` tool's.

Clips are encoded by the ``ffmpeg`` binary that imageio-ffmpeg ships (:func:`make_clip`: constant rate, any
container or codec, audio, start offsets; :func:`remux`/:func:`with_rotation`: metadata) or by PyAV
(:func:`make_vfr_clip`: explicit timestamps). Tests needing the binary carry the :data:`needs_ffmpeg` mark,
which skips them with a reason when it is missing.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator, Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

GRID = 4  # cells per side
LOW, HIGH = 40, 215  # grey levels of a 0 and a 1 bit


def ffmpeg_exe() -> str | None:
    """Path of the imageio-ffmpeg binary, or None if it is not installed."""
    try:
        import imageio_ffmpeg

        exe = imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # noqa: BLE001 - any failure means "no reference binary"
        return None
    return exe if exe and os.access(exe, os.X_OK) else None


needs_ffmpeg = pytest.mark.skipif(ffmpeg_exe() is None, reason="imageio-ffmpeg's ffmpeg binary is not available")


# ----------------------------------------------------------------------------------------------- index frames


def index_frame(index: int, width: int = 128, height: int = 96) -> np.ndarray:
    """An ``(height, width, 3)`` uint8 RGB frame showing ``index`` (0..65535) as grey cells, with a red tint
    that varies with the index (so neighbouring frames differ in colour too)."""
    if not 0 <= index < 1 << (GRID * GRID):
        raise ValueError(f"index {index} does not fit in {GRID * GRID} bits")
    img = np.empty((height, width, 3), np.uint8)
    ys = np.linspace(0, height, GRID + 1).astype(int)
    xs = np.linspace(0, width, GRID + 1).astype(int)
    for bit in range(GRID * GRID):
        r, c = divmod(bit, GRID)
        img[ys[r] : ys[r + 1], xs[c] : xs[c + 1]] = HIGH if index >> bit & 1 else LOW
    img[..., 0] = np.clip(img[..., 0].astype(int) + (index * 7) % 20 - 10, 0, 255)
    return img


def read_index(rgb: np.ndarray) -> int:
    """Read back the index drawn by :func:`index_frame` (from the middle half of every cell)."""
    grey = rgb[..., 1].astype(np.float32)
    h, w = grey.shape
    ys, xs = np.linspace(0, h, 2 * GRID + 1), np.linspace(0, w, 2 * GRID + 1)  # cell edges and centres
    value = 0
    for bit in range(GRID * GRID):
        r, c = divmod(bit, GRID)
        y0, y1 = (ys[2 * r] + ys[2 * r + 1]) / 2, (ys[2 * r + 1] + ys[2 * r + 2]) / 2
        x0, x1 = (xs[2 * c] + xs[2 * c + 1]) / 2, (xs[2 * c + 1] + xs[2 * c + 2]) / 2
        if grey[int(y0) : int(y1), int(x0) : int(x1)].mean() > (LOW + HIGH) / 2:
            value |= 1 << bit
    return value


# ------------------------------------------------------------------------------------------------------ clips


def _run(args: Sequence[str], stdin: bytes | None = None) -> bytes:
    exe = ffmpeg_exe()
    if exe is None:
        pytest.skip("imageio-ffmpeg's ffmpeg binary is not available")
    cmd = [exe, "-hide_banner", "-loglevel", "error", *([] if stdin is not None else ["-nostdin"]), *args]
    proc = subprocess.run(cmd, input=stdin, capture_output=True, check=False, timeout=120)
    if proc.returncode != 0:
        err = proc.stderr.decode(errors="replace")[-2000:]
        raise RuntimeError(f"ffmpeg {' '.join(args)} failed: {err}")
    return proc.stdout


X264 = ("-c:v", "libx264", "-preset", "ultrafast", "-crf", "12", "-pix_fmt", "yuv420p")


def make_clip(
    path: Path,
    n_frames: int = 50,
    fps: str | float | Fraction = 25,
    size: tuple[int, int] = (128, 96),
    codec_args: Sequence[str] = X264,
    input_args: Sequence[str] = (),
    output_args: Sequence[str] = (),
    audio: bool = False,
    first_index: int = 0,
) -> Path:
    """Encode a constant-rate clip of index frames with the ffmpeg binary; the container follows the suffix.

    ``fps`` may be a string such as ``"30000/1001"``. ``input_args`` go before the frames' ``-i`` (e.g.
    ``["-itsoffset", "0.02"]`` to start the video later than the audio); ``audio`` adds a sine track. Frames show
    ``first_index``, ``first_index + 1``, ... (so that clips joined end to end stay distinguishable).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    w, h = size
    raw = b"".join(index_frame(first_index + i, w, h).tobytes() for i in range(n_frames))
    args = [*input_args, "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-framerate", str(fps)]
    args += ["-i", "-"]
    if audio:
        # A sine as long as the video: `-shortest` alone cuts an endless source only after what the muxer has
        # buffered, which varies with the machine's load (1.35 s or 1.66 s for the same clip).
        seconds = float(n_frames / Fraction(str(fps)))
        args += ["-f", "lavfi", "-i", f"sine=frequency=440:sample_rate=48000:duration={seconds:.6f}", "-shortest"]
        args += ["-c:a", "aac"]
    _run([*args, *codec_args, *output_args, "-y", str(path)], stdin=raw)
    return path


def synthetic_clip_frames(path: Path, n_frames: int, width: int, height: int, seed: int) -> list[np.ndarray]:
    """The first ``n_frames`` of a synthetic colonoscopy clip (with its lighting changes), written to ``path`` as
    H.264 and decoded (RGB): the frames a host reads from a real recording, compression included."""
    from colonlight.sources import clip_frames
    from colonlight.synth import SynthConfig, generate_clip
    from colonlight.video import VideoWriter

    cfg = SynthConfig.sample(np.random.default_rng(seed), split="train", width=width, height=height)
    with VideoWriter(path, fps=18) as writer:
        for i, f in enumerate(generate_clip(cfg, seed=seed)):
            if i == n_frames:
                break
            writer.write(f.image)
    return [f.image for f in clip_frames(path, fps=None)]


def make_solid_clip(path: Path, size: tuple[int, int], n_frames: int = 2, fps: int = 6) -> Path:
    """A grey H.264 clip from FFmpeg's ``color`` source: cheap at any size (e.g. a tiny file of huge frames)."""
    w, h = size
    _run(
        [
            "-f",
            "lavfi",
            "-i",
            f"color=gray:s={w}x{h}:r={fps}",
            "-frames:v",
            str(n_frames),
            "-c:v",
            "libx264",
            "-preset",
            "ultrafast",
            "-y",
            str(path),
        ]
    )
    return Path(path)


def make_vfr_clip(
    path: Path,
    times_s: Sequence[float],
    size: tuple[int, int] = (128, 96),
    time_base: Fraction = Fraction(1, 1000),
    codec: str = "libx264",
) -> Path:
    """Encode frame ``i`` at presentation time ``times_s[i]`` (variable frame rate) with PyAV."""
    import av

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    w, h = size
    with av.open(str(path), mode="w") as out:
        stream = out.add_stream(codec, rate=30)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        stream.time_base = time_base
        stream.codec_context.time_base = time_base
        if codec == "libx264":
            stream.options = {"preset": "ultrafast", "crf": "12"}
        for i, t in enumerate(times_s):
            frame = av.VideoFrame.from_ndarray(index_frame(i, w, h), format="rgb24")
            frame.pts = round(t / time_base)
            frame.time_base = time_base
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


def vfr_times(n: int, seed: int = 7) -> list[float]:
    """Irregular presentation times: bursts (faster than 18 fps), normal gaps and stalls (slower)."""
    rng = np.random.default_rng(seed)
    deltas = rng.choice([0.008, 0.016, 1 / 30, 0.04, 0.05, 0.0555, 0.06, 0.1, 0.25], size=n - 1)
    return [0.0, *np.cumsum(deltas).tolist()]


def remux(src: Path, dst: Path, input_args: Sequence[str] = (), output_args: Sequence[str] = ()) -> Path:
    """Copy ``src``'s streams into ``dst`` without re-encoding, e.g. to change metadata or container."""
    _run([*input_args, "-i", str(src), "-c", "copy", *output_args, "-y", str(dst)])
    return Path(dst)


def with_rotation(src: Path, dst: Path, degrees: float, hflip: bool = False) -> Path:
    """``src`` with a display matrix turning it ``degrees`` counter-clockwise for display (as a phone
    marks a portrait recording), optionally mirrored."""
    return remux(src, dst, ["-display_rotation", str(degrees), *(["-display_hflip"] if hflip else [])])


def joined(parts: Sequence[Path], dst: Path) -> Path:
    """The bytes of ``parts`` end to end (``cat a.ts b.ts > dst``), as recorders and careless copies join files."""
    Path(dst).write_bytes(b"".join(Path(p).read_bytes() for p in parts))
    return Path(dst)


def truncated_copy(src: Path, dst: Path, keep: float) -> Path:
    """The first ``keep`` fraction of ``src``'s bytes, as left by an interrupted copy or recording."""
    data = Path(src).read_bytes()
    Path(dst).write_bytes(data[: int(len(data) * keep)])
    return Path(dst)


def corrupted_copy(src: Path, dst: Path, start: float = 0.3, length: float = 0.4, seed: int = 1) -> Path:
    """``src`` with a span of its bytes (fractions of the size) overwritten by random bytes."""
    data = bytearray(Path(src).read_bytes())
    a, n = int(len(data) * start), int(len(data) * length)
    data[a : a + n] = np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()
    Path(dst).write_bytes(bytes(data))
    return Path(dst)


def zero_byte_file(path: Path) -> Path:
    Path(path).write_bytes(b"")
    return Path(path)


def text_file(path: Path, text: str = "This is not a video.\n" * 50) -> Path:
    Path(path).write_text(text, encoding="utf-8")
    return Path(path)


# ---------------------------------------------------------------------------------------------- image folders


def make_image_folder(
    folder: Path, n: int = 12, size: tuple[int, int] = (64, 48), fmt: str = "png", name: str = "frame{i}"
) -> list[Path]:
    """Write ``n`` index images named ``name.format(i=i)`` + ``.fmt``; returned in index order."""
    import cv2

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        ok, buf = cv2.imencode("." + fmt, cv2.cvtColor(index_frame(i, *size), cv2.COLOR_RGB2BGR))
        assert ok
        p = folder / f"{name.format(i=i)}.{fmt}"
        buf.tofile(str(p))
        paths.append(p)
    return paths


# ------------------------------------------------------------------------------- what the ffmpeg tool decodes


def ffmpeg_frames(path: Path, vf: str | None = None) -> Iterator[np.ndarray]:
    """RGB frames as ``ffmpeg -i path [-vf vf]`` outputs them: autorotate on, no output-side rate change
    (``-fps_mode passthrough``), the first video stream only, audio not used."""
    args = ["-i", str(path), "-map", "0:v:0", *(["-vf", vf] if vf else [])]
    args += ["-fps_mode", "passthrough", "-f", "image2pipe", "-c:v", "ppm", "-pix_fmt", "rgb24", "-"]
    data = _run(args)
    pos = 0
    while pos < len(data):  # a PPM per frame: "P6 <w> <h> 255" + one whitespace byte + w*h*3 bytes
        fields: list[bytes] = []
        while len(fields) < 4:
            while data[pos : pos + 1].isspace():
                pos += 1
            end = pos
            while not data[end : end + 1].isspace():
                end += 1
            fields.append(data[pos:end])
            pos = end
        pos += 1
        w, h = int(fields[1]), int(fields[2])
        yield np.frombuffer(data, np.uint8, w * h * 3, pos).reshape(h, w, 3)
        pos += w * h * 3


def ffmpeg_decoded(data: bytes, fmt: str, width: int, height: int) -> np.ndarray:
    """``(N, height, width, 3)`` RGB frames as the ffmpeg tool decodes a ``fmt`` stream (``yuv4mpegpipe``,
    ``mpegts``) held in memory: what a player downstream of a pipe would see."""
    args = ["-f", fmt, "-i", "-", "-f", "rawvideo", "-pix_fmt", "rgb24", "-"]
    return np.frombuffer(_run(args, stdin=data), np.uint8).reshape(-1, height, width, 3)


def ffmpeg_fps_indices(path: Path, fps: str | float = 18) -> list[int]:
    """Source indices of the frames ``ffmpeg -i path -vf fps=<fps>`` outputs."""
    return [read_index(f) for f in ffmpeg_frames(path, vf=f"fps={fps}")]


def make_noise_clip(
    path: Path, n_frames: int = 30, fps: float = 25, size: tuple[int, int] = (320, 240), seed: int = 0
) -> Path:
    """A clip of random pixels: its frames barely compress (a PNG of one is ~the raw size), so that a test can
    fill a small disk with a few of them."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    w, h = size
    raw = np.random.default_rng(seed).integers(0, 256, (n_frames, h, w, 3), dtype=np.uint8).tobytes()
    args = ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-framerate", str(fps), "-i", "-"]
    _run([*args, *X264, "-y", str(path)], stdin=raw)
    return path


def flat_png(width: int, height: int, level: int = 0, rows: int | None = None) -> bytes:
    """A valid 8-bit grey PNG whose header declares ``width x height``, every pixel ``level``, compressed row by
    row: a huge image in a few tens of kB, never held uncompressed. ``rows`` (default: all) writes only the first
    rows: a header any reader takes, image data that ends early."""
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    packer = zlib.compressobj(6)
    row = b"\x00" + bytes([level]) * width  # filter byte "none", then the row
    data = b"".join(packer.compress(row) for _ in range(height if rows is None else rows)) + packer.flush()
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)  # 8-bit greyscale
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", data) + chunk(b"IEND", b"")
