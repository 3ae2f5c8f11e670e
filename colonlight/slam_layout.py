"""A clip's output laid out as SLAM and SfM tools read it, beside ``frames/``.

* ``times.txt``: DSO's timestamps (``dso_dataset files=OUT/clip/frames`` reads ``OUT/clip/times.txt``), one line
  per frame: its index (the frame file's number) and its source time in seconds.
* ``rgb.txt``: the TUM RGB-D layout that ORB-SLAM3's ``mono_tum`` reads: three comment lines, then
  ``time path`` per frame, the path relative to the clip's folder (``frames/000000.png``).
* ``camera.txt`` (DSO: Pinhole, RadTan, FOV, EquiDistant or KannalaBrandt; first line the model and its
  parameters, then the input size, ``crop``/``full``/``none``/output intrinsics, the output size) or
  ``cameras.txt`` (COLMAP's text format), copied from ``--camera FILE``. The camera must be for the frames'
  size. ``colonlight enhance`` never resizes frames, so it copies the file byte for byte after checking its size;
  :func:`camera_for_frames` rescales it for callers whose frames differ in size from their source.

Times are the frames' source presentation times (relative to the stream's start), so a SLAM system sees the
video's own timing, also for variable-frame-rate sources.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .atomic import read_regular_file, write_bytes_atomic
from .errors import InputError

TIMES_FILE = "times.txt"
TUM_RGB_FILE = "rgb.txt"
DSO_CAMERA_FILE = "camera.txt"
COLMAP_CAMERAS_FILE = "cameras.txt"
CAMERA_FILES = (DSO_CAMERA_FILE, COLMAP_CAMERAS_FILE)

#: DSO's camera models and their parameter counts (``src/util/Undistort.cpp``); a first line of bare numbers is
#: RadTan for 8 of them and Pinhole (last 0) or FOV for 5, as DSO reads it.
DSO_MODELS = {"Pinhole": 5, "FOV": 5, "RadTan": 8, "EquiDistant": 8, "KannalaBrandt": 8}
_DSO_OUTPUT_WORDS = ("crop", "full", "none")
#: COLMAP's camera models: parameter count and whether they have one focal length (f) or two (fx, fy); in every
#: one of them the parameters start with the focal length(s) followed by cx, cy.
COLMAP_MODELS: dict[str, tuple[int, bool]] = {
    "SIMPLE_PINHOLE": (3, True),
    "PINHOLE": (4, False),
    "SIMPLE_RADIAL": (4, True),
    "RADIAL": (5, True),
    "OPENCV": (8, False),
    "OPENCV_FISHEYE": (8, False),
    "FULL_OPENCV": (12, False),
    "FOV": (5, False),
    "SIMPLE_RADIAL_FISHEYE": (4, True),
    "RADIAL_FISHEYE": (5, True),
    "THIN_PRISM_FISHEYE": (12, False),
    "RAD_TAN_THIN_PRISM_FISHEYE": (16, False),
    "SIMPLE_DIVISION": (4, True),
    "DIVISION": (5, False),
}

Size = tuple[int, int]  # (width, height)
#: A resize whose x and y scales differ by more than this changes the aspect ratio (more than whole-pixel rounding).
_ASPECT_TOLERANCE = 0.01


@dataclass(frozen=True)
class CameraFile:
    """A camera file as given: its name, its text, its kind (``dso`` | ``colmap``) and the image size(s) it is
    calibrated for (DSO: one; COLMAP: one per camera line)."""

    name: str
    text: str
    kind: str
    sizes: tuple[Size, ...]

    @property
    def output_name(self) -> str:
        return DSO_CAMERA_FILE if self.kind == "dso" else COLMAP_CAMERAS_FILE

    @property
    def digest(self) -> str:
        return hashlib.sha256(self.text.encode("utf-8")).hexdigest()


#: A number as DSO and COLMAP read one (C's strtod, std::stoi): ASCII only. Python's float() and int() also take
#: other scripts' digits ('١٢٨'), '1_000' and superscripts pass str.isdigit(): a file with them passed the check and
#: was copied beside every clip, where the SLAM tool then failed on it.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_INTEGER = re.compile(r"[0-9]+")


#: Blanks within a line as DSO (std::getline, sscanf) and COLMAP (std::getline, StringTrim, >>) read them: C's
#: isspace. Python's splitlines() and split() also break at U+2028, U+0085, U+00A0, form feed as a line end and
#: more, so a file the SLAM tool misreads would pass the check.
_BLANKS = " \t\r\v\f"
_BLANK_RUN = re.compile(f"[{re.escape(_BLANKS)}]+")


def _lines(text: str) -> list[str]:
    """The file's lines as DSO and COLMAP see them: split at "\\n" only, a CRLF file's "\\r" dropped."""
    lines = [line.removesuffix("\r") for line in text.split("\n")]
    return lines[:-1] if lines and lines[-1] == "" else lines


def _tokens(line: str) -> list[str]:
    """A line's whitespace-separated tokens, as C's streams and sscanf read them."""
    return [t for t in _BLANK_RUN.split(line) if t]


def _numbers(tokens: Sequence[str], what: str) -> list[float]:
    if not all(_NUMBER.fullmatch(t) for t in tokens):
        raise ValueError(f"{what}: expected numbers, got {' '.join(tokens)!r}")
    values = [float(t) for t in tokens]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what}: numbers must be finite")
    return values


def _size(line: str, what: str) -> Size:
    tokens = _tokens(line)
    if len(tokens) != 2 or not all(_INTEGER.fullmatch(t) for t in tokens) or min(int(t) for t in tokens) < 1:
        raise ValueError(f"{what}: expected 'width height', got {line.strip(_BLANKS)!r}")
    return int(tokens[0]), int(tokens[1])


def _dso_model(line: str) -> tuple[str, str, list[float]]:
    """DSO's first line as ``(model, prefix, parameters)``; ``prefix`` is the model word as written, or ''."""
    tokens = _tokens(line)
    if tokens and tokens[0] in DSO_MODELS:
        model, params = tokens[0], _numbers(tokens[1:], "line 1")
        if len(params) != DSO_MODELS[model]:
            raise ValueError(f"line 1: {model} takes {DSO_MODELS[model]} parameters, got {len(params)}")
        return model, model, params
    params = _numbers(tokens, "line 1 (a model name: Pinhole, RadTan, FOV, EquiDistant, KannalaBrandt, then numbers)")
    if len(params) == 8:
        return "RadTan", "", params
    if len(params) == 5:
        return ("Pinhole" if params[4] == 0 else "FOV"), "", params
    raise ValueError(f"line 1: expected a model name and its parameters, or 5 or 8 numbers; got {len(params)} numbers")


def _parse_dso(lines: list[str]) -> tuple[Size, ...]:
    if len(lines) < 4:
        raise ValueError(
            f"a DSO camera file has 4 lines (model, input size, crop/full/none, output size); got {len(lines)}"
        )
    _dso_model(lines[0])
    in_size = _size(lines[1], "line 2 (input size)")
    third = lines[2].strip(_BLANKS)
    if (
        third not in _DSO_OUTPUT_WORDS
        and len(_numbers(_tokens(third), "line 3 (crop, full, none or 'fx fy cx cy 0')")) != 5
    ):
        raise ValueError("line 3: expected crop, full, none or 5 numbers (relative output intrinsics)")
    _size(lines[3], "line 4 (output size)")
    return (in_size,)


def _colmap_lines(lines: list[str]) -> list[tuple[int, list[str]]]:
    """The camera lines of a COLMAP cameras.txt as ``(line index, tokens)``; comments and blanks skipped."""
    return [
        (i, _tokens(line))
        for i, line in enumerate(lines)
        if line.strip(_BLANKS) and not line.lstrip(_BLANKS).startswith("#")
    ]


def _parse_colmap(lines: list[str]) -> tuple[Size, ...]:
    sizes = []
    cameras = _colmap_lines(lines)
    if not cameras:
        raise ValueError("no camera line (CAMERA_ID MODEL WIDTH HEIGHT PARAMS...)")
    for i, tokens in cameras:
        where = f"line {i + 1}"
        if len(tokens) < 5 or not _INTEGER.fullmatch(tokens[0]):
            raise ValueError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...")
        model = tokens[1]
        size = _size(" ".join(tokens[2:4]), f"{where} (WIDTH HEIGHT)")
        params = _numbers(tokens[4:], f"{where} (PARAMS)")
        if model in COLMAP_MODELS and len(params) != COLMAP_MODELS[model][0]:
            raise ValueError(f"{where}: {model} takes {COLMAP_MODELS[model][0]} parameters, got {len(params)}")
        sizes.append(size)
    return tuple(sizes)


def _looks_like_colmap(lines: list[str]) -> bool:
    cameras = _colmap_lines(lines)
    first = cameras[0][1] if cameras else []
    return len(first) >= 2 and _INTEGER.fullmatch(first[0]) is not None and first[1].isupper()


def parse_camera(text: str, name: str) -> CameraFile:
    """Recognise and check a DSO ``camera.txt`` or a COLMAP ``cameras.txt``; ``InputError`` names ``name``."""
    if text.startswith("\ufeff"):  # Windows editors save UTF-8 so; judged as DSO, it failed with a misleading cause
        raise InputError(
            f"{name}: starts with a byte-order mark (U+FEFF), which DSO and COLMAP do not read; save it without one"
        )
    lines = _lines(text)
    kind = "colmap" if _looks_like_colmap(lines) else "dso"
    try:
        sizes = _parse_colmap(lines) if kind == "colmap" else _parse_dso(lines)
    except ValueError as exc:
        label = "COLMAP cameras.txt" if kind == "colmap" else "DSO camera.txt"
        raise InputError(f"{name}: not a valid {label} ({exc})") from None
    return CameraFile(name=name, text=text, kind=kind, sizes=sizes)


def read_camera(path: Path) -> CameraFile:
    """Read and check the camera file at ``path`` (``InputError`` naming it if unreadable or malformed)."""
    path = Path(path)
    try:
        text = read_regular_file(path).decode("utf-8")  # a FIFO is refused, not waited on
        text = text.replace("\r\n", "\n").replace("\r", "\n")  # the newlines read_text gave (universal)
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise InputError(f"{path}: cannot read the camera file ({reason})") from None
    return parse_camera(text, str(path))


# ------------------------------------------------------------------------------------------------------ rescale


def _fmt(value: float) -> str:
    return format(value, ".10g")


def _rescale_dso(cam: CameraFile, to: Size) -> str:
    lines = _lines(cam.text)
    (w0, h0), (w1, h1) = cam.sizes[0], to
    sx, sy = w1 / w0, h1 / h0
    model, prefix, p = _dso_model(lines[0])
    if not (p[2] < 1 and p[3] < 1):  # absolute pixels; DSO's relative form (cx, cy < 1) needs no change
        # DSO puts pixel centres at integers: x' + 0.5 = (x + 0.5) * s (see its relative-format conversion).
        p[0], p[1] = p[0] * sx, p[1] * sy
        p[2], p[3] = (p[2] + 0.5) * sx - 0.5, (p[3] + 0.5) * sy - 0.5
    lines[0] = " ".join(([prefix] if prefix else []) + [_fmt(v) for v in p])
    lines[1] = f"{w1} {h1}"
    ow, oh = _size(lines[3], "line 4")
    lines[3] = f"{w1} {h1}" if (ow, oh) == (w0, h0) else f"{max(1, round(ow * sx))} {max(1, round(oh * sy))}"
    return "\n".join(lines) + "\n"


def _rescale_colmap(cam: CameraFile, to: Size) -> str:
    lines = _lines(cam.text)
    for i, tokens in _colmap_lines(lines):
        model, (w0, h0) = tokens[1], (int(tokens[2]), int(tokens[3]))
        if model not in COLMAP_MODELS:
            raise InputError(f"{cam.name}: cannot rescale COLMAP model {model} (unknown to colonlight)")
        sx, sy = to[0] / w0, to[1] / h0
        p = [float(t) for t in tokens[4:]]
        if COLMAP_MODELS[model][1]:  # one focal length: as COLMAP's Camera::Rescale, the mean of the two scales
            if abs(sx - sy) > _ASPECT_TOLERANCE * max(sx, sy):
                raise InputError(
                    f"{cam.name}: {model} has one focal length; {w0}x{h0} -> {to[0]}x{to[1]} changes the aspect ratio"
                )
            p[0], p[1], p[2] = p[0] * (sx + sy) / 2, p[1] * sx, p[2] * sy
        else:  # COLMAP's pixel centres are at +0.5, so focal lengths and the principal point scale alike
            p[0], p[1], p[2], p[3] = p[0] * sx, p[1] * sy, p[2] * sx, p[3] * sy
        lines[i] = " ".join([tokens[0], model, str(to[0]), str(to[1]), *(_fmt(v) for v in p)])
    return "\n".join(lines) + "\n"


def rescale_camera(cam: CameraFile, to: Size) -> str:
    """The camera file's text for images resized from its calibrated size to ``to`` (width, height)."""
    return _rescale_dso(cam, to) if cam.kind == "dso" else _rescale_colmap(cam, to)


def camera_for_frames(cam: CameraFile, frame_size: Size, source_size: Size | None = None) -> str:
    """The camera text to write beside frames of ``frame_size`` made from a source of ``source_size`` (default:
    the same; ``colonlight enhance`` never resizes). The camera must be calibrated for the source's size: then it
    is copied as it is, or rescaled when the frames were resized. A mismatch is an ``InputError``."""
    source_size = source_size or frame_size
    wrong = [s for s in cam.sizes if s != source_size]
    if wrong:
        w, h = wrong[0]
        raise InputError(
            f"{cam.name}: calibrated for {w}x{h} images, but this clip's frames are "
            f"{source_size[0]}x{source_size[1]} (colonlight enhance writes frames at the source's size)"
        )
    return cam.text if source_size == frame_size else rescale_camera(cam, frame_size)


# -------------------------------------------------------------------------------------------------- the layout


def times_text(records: Sequence[dict[str, Any]]) -> str:
    """DSO's ``times.txt``: ``index time_s`` per frame, the index as the frame file's number."""
    return "".join(f"{r['index']:06d} {r['source_time_s']:.6f}\n" for r in records)


def tum_rgb_text(records: Sequence[dict[str, Any]], fmt: str, frames_dir: str = "frames") -> str:
    """TUM's ``rgb.txt``: three comment lines (``mono_tum`` skips exactly three), then ``time path`` per frame."""
    head = (
        "# color images\n"
        "# written by colonlight enhance: source time (s) of each enhanced frame\n"
        "# timestamp filename\n"
    )
    return head + "".join(f"{r['source_time_s']:.6f} {frames_dir}/{r['index']:06d}.{fmt}\n" for r in records)


def write_slam_layout(
    out_dir: Path, records: Sequence[dict[str, Any]], frame_format: str | None, camera: tuple[str, str] | None
) -> None:
    """Write ``times.txt``, ``rgb.txt`` (when frames are written: ``frame_format``) and the camera file (when given
    as ``(kind's file name, text)``) into ``out_dir``, each atomically; remove those a previous run left and this
    one does not write."""
    out_dir = Path(out_dir)
    write_bytes_atomic(out_dir / TIMES_FILE, times_text(records).encode("utf-8"))
    if frame_format:
        write_bytes_atomic(out_dir / TUM_RGB_FILE, tum_rgb_text(records, frame_format).encode("utf-8"))
    else:
        (out_dir / TUM_RGB_FILE).unlink(missing_ok=True)
    for name in CAMERA_FILES:
        if camera is None or name != camera[0]:
            (out_dir / name).unlink(missing_ok=True)
    if camera is not None:
        write_bytes_atomic(out_dir / camera[0], camera[1].encode("utf-8"))


def clip_camera(camera: tuple[str, str] | None, frame_hw: tuple[int, int]) -> tuple[str, str] | None:
    """For a clip whose frames are ``(height, width)``: the camera given as ``(file name, text)`` checked against
    them, as ``(output file name, text)``; ``None`` without a camera. Called before anything is written."""
    if camera is None:
        return None
    cam = parse_camera(camera[1], camera[0])
    return cam.output_name, camera_for_frames(cam, (frame_hw[1], frame_hw[0]))


def camera_setting(camera: tuple[str, str] | None) -> dict[str, str]:
    """What of the camera decides a clip's outputs (its text's sha256), for the clip's settings record."""
    return {} if camera is None else {"camera_sha256": hashlib.sha256(camera[1].encode("utf-8")).hexdigest()}
