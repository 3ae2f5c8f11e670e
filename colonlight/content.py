"""The content area of a scope's picture: the field of view inside its black border, less the fixed on-screen text.

Real colonoscopy frames show the scene in a round or octagonal field of view on black, with text (patient
fields, time, scope settings) keyed over the picture. A method that sees the whole frame counts the border and
the text as scene: the black pulls a gamma network towards brightening, a histogram method spends its range on
it. ``--content auto`` (:class:`ContentStream`) lets the method see the content only and writes the border and
text pixels unchanged.

Detection works on blocks of ``DETECT_FRAMES`` frames, from the grey level's per-pixel maximum and minimum over
the block:

- field of view: the convex hull of the largest region that was lit (brighter than ``DARK_LEVEL``) in the block.
  It counts as a border only if it is a real one: at least ``MIN_BORDER_FRACTION`` of the frame, nearly all
  flat and mostly dark outside (the rest is text), with a sharp step at its edge (a dark lumen or vignetted
  corner fades; a border does not). A frame without a border is therefore left exactly alone.
- overlays: pixels inside the field of view that stayed constant (range <= ``STATIC_RANGE``) while the scene
  changed (median range >= ``MOVING_RANGE``), in groups with text-like contrast; a block whose scene did not
  change says nothing about overlays.

The first block decides the area before any frame goes to the method (the stream holds up to ``DETECT_FRAMES``
frames back once, at the start; a live stream, which cannot wait, decides on its first frame alone,
:func:`live_content_stream`); every later block is a candidate, adopted only when ``CHANGE_BLOCKS``
consecutive candidates agree with each other and differ from the current area (hysteresis: a dark moment does
not shrink the field of view). The method gets the content's bounding box with the other pixels filled with the
content's mean colour; its output is pasted back at content pixels only.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from .content_area import ContentArea, iou
from .content_mask import ContentMask, load_content_mask
from .errors import FrameShapeError, InputError, OptionError
from .methods import create_method
from .methods.base import FrameResult, Method, MethodStream, check_frame

ContentMode = Literal["auto", "full"]
CONTENT_MODES: tuple[str, ...] = ("auto", "full")
DEFAULT_CONTENT: ContentMode = "auto"

#: Grey level at or below which a pixel counts as unlit (a decoded black border is 0..~5; H.264 adds a little).
DARK_LEVEL = 24
#: Median step (grey levels of the block maximum) across the field of view's edge, a few pixels in vs. out.
EDGE_STEP = 24
#: The lit region must cover at least this share of the frame for a block to say anything about the border.
MIN_LIT_FRACTION = 0.05
#: Shares of the border that must be flat (unlit or text), and unlit (text never covers half of it).
BORDER_FLAT_SHARE = 0.9
BORDER_DARK_SHARE = 0.5
#: Range (grey levels over a block) at or below which a border pixel counts as flat.
FLAT_RANGE = 8
#: A border smaller than this share of the frame is ignored (not worth a different method input).
MIN_BORDER_FRACTION = 0.01
#: Range at or below which a pixel counts as static, and the scene's median range needed to tell overlays.
STATIC_RANGE = 3
MOVING_RANGE = 12
#: An overlay group must contain a step at least this large (text on a picture, with its dark outline).
TEXT_CONTRAST = 60
#: Pixels this bright in every frame (specular glints, clipped text) join an overlay only beside static pixels.
SATURATED = 250
#: Frames per detection block, and agreeing blocks needed to change the area.
DETECT_FRAMES = 18
#: Frames a live stream's first decision takes (no frame is held back): a one-frame block finds a border as
#: often as an 18-frame one (all 128 discs drawn on validation clips, seeds 720128-255; session 26), and later
#: blocks of ``DETECT_FRAMES`` correct it. Seen whole, a disc border drove the shipped network to gamma 0.12.
LIVE_FIRST_FRAMES = 1
CHANGE_BLOCKS = 2

_DISC3 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
_DISC5 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
_SQUARE3 = np.ones((3, 3), np.uint8)


def parse_content(value: str | Path) -> str:
    """``"auto"`` or ``"full"`` (any case), else a readable content mask (``colonlight content``'s, or one drawn by
    hand: 255 scene, 0 border) read now, once for the run: a :class:`~colonlight.content_mask.ContentMask`, the
    text of its absolute path holding the hash recorded and the area used; OptionError naming the file and the
    cause otherwise. A mask parsed already is kept as it is, never read again.
    For the shells that run on the user's own files (``enhance``, ``stream``, ``evaluate``); the service takes
    :func:`parse_content_mode`'s two words only, never a path on the server."""
    if isinstance(value, ContentMask):  # parsed options passed on (a clip's stream, evaluate_clips, replace())
        return value
    word = str(value).strip().lower()
    if word in CONTENT_MODES:
        return word
    wanted = f"content must be {', '.join(CONTENT_MODES)} or a mask image"
    if not str(value).strip():
        raise OptionError(f"{wanted}, got {value!r}")
    try:
        return load_content_mask(Path(value))
    except InputError as exc:
        raise OptionError(f"{wanted}: {exc}") from None


def content_setting(content: str) -> str | dict[str, str]:
    """What an output records of ``content`` (:func:`parse_content`'s): the word, or a mask's path with the
    SHA-256 of the bytes its area was read from, so that the same mask gives the same record and an edited one
    is seen as another setting."""
    mask = parse_content(content)
    if not isinstance(mask, ContentMask):
        return mask
    return {"mask": str(mask), "sha256": mask.sha256}


def parse_content_mode(value: str) -> ContentMode:
    """``"auto"`` or ``"full"`` (any case); anything else raises ``ValueError``."""
    word = str(value).strip().lower()
    if word not in CONTENT_MODES:
        raise OptionError(f"content must be one of {', '.join(CONTENT_MODES)}, got {value!r}")
    return word  # type: ignore[return-value]


# ----------------------------------------------------------------------------------------------- detection


class BlockStats:
    """Per-pixel grey maximum and minimum over the frames of one block."""

    def __init__(self) -> None:
        self.high: np.ndarray | None = None
        self.low: np.ndarray | None = None
        self.count = 0

    def add(self, frame: np.ndarray) -> None:
        grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
        if self.high is None or self.low is None:
            self.high, self.low = grey, grey.copy()
        else:
            cv2.max(self.high, grey, dst=self.high)
            cv2.min(self.low, grey, dst=self.low)
        self.count += 1


def detect_fov(high: np.ndarray, low: np.ndarray) -> np.ndarray | None:
    """``(H, W)`` bool field of view from a block's grey maximum and minimum: all True if there is no border,
    ``None`` if too little of the frame was lit to tell."""
    h, w = high.shape
    everything = np.ones((h, w), bool)
    lit = cv2.morphologyEx((high > DARK_LEVEL).astype(np.uint8), cv2.MORPH_OPEN, _DISC5)  # detaches thin text
    # The hull of a region's outline is the hull of the region (and far cheaper than of all its pixels).
    outlines, _ = cv2.findContours(lit, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not outlines:
        return None
    areas = [cv2.contourArea(c) for c in outlines]
    biggest = outlines[int(np.argmax(areas))]
    if max(areas) < MIN_LIT_FRACTION * h * w:
        return None
    hull = cv2.convexHull(biggest)
    fov_u8 = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(fov_u8, hull, 1)
    fov = fov_u8.astype(bool)
    border = ~fov
    if border.mean() < MIN_BORDER_FRACTION or not is_dark_border(high, low, border):
        return everything
    # The step at the edge, only where the edge is not the frame's own edge.
    inside = fov_u8 - cv2.erode(fov_u8, _DISC5, iterations=2, borderType=cv2.BORDER_REPLICATE)
    outside = cv2.dilate(fov_u8, _DISC5, iterations=2) - fov_u8
    inner, outer = high[inside.astype(bool)], high[outside.astype(bool)]
    if inner.size == 0 or outer.size == 0 or median_u8(inner) - median_u8(outer) < EDGE_STEP:
        return everything
    # The hull runs through the outermost lit pixels; unlit pixels along its inside (a soft or compressed edge)
    # are border too.
    ring = inside.astype(bool) & (high <= DARK_LEVEL) & (high - low <= FLAT_RANGE)
    bounded: np.ndarray = fov & ~ring
    return bounded


def median_u8(values: np.ndarray) -> int:
    """The (lower) median of uint8 values, from their histogram: linear time, where sorting 2 M pixels is not."""
    column = np.ascontiguousarray(values).reshape(-1, 1)
    counts = np.cumsum(cv2.calcHist([column], [0], None, [256], [0, 256]).ravel())
    return int(np.searchsorted(counts, (counts[-1] + 1) // 2))


def is_dark_border(high: np.ndarray, low: np.ndarray, border: np.ndarray) -> bool:
    """True if nearly all of ``border`` stayed flat over the block and most of it unlit (the rest is text)."""
    high, low, border = high[::2, ::2], low[::2, ::2], border[::2, ::2]  # shares: every 4th pixel tells them
    if not border.any():
        return False
    high_b = high[border]
    flat = float((high_b - low[border] <= FLAT_RANGE).mean())
    return flat >= BORDER_FLAT_SHARE and float((high_b <= DARK_LEVEL).mean()) >= BORDER_DARK_SHARE


def detect_overlay(high: np.ndarray, low: np.ndarray, fov: np.ndarray) -> np.ndarray | None:
    """``(H, W)`` bool fixed-text pixels inside ``fov``, or ``None`` when the block's scene did not change enough
    to tell (static text from a static scene)."""
    spread = cv2.subtract(high, low)
    if not fov.any() or median_u8(spread[::2, ::2][fov[::2, ::2]]) < MOVING_RANGE:
        return None
    # Text is looked for over the whole frame: a glyph just outside the field of view has its outline inside.
    static = (spread <= STATIC_RANGE) & (high > DARK_LEVEL) & (low < SATURATED)
    if not static.any():
        return np.zeros_like(fov)
    clipped = low >= SATURATED
    candidate = (static | (clipped & cv2.dilate(static.astype(np.uint8), _DISC3).astype(bool))).astype(np.uint8)
    contrast = cv2.morphologyEx(high, cv2.MORPH_GRADIENT, _DISC3)
    # Text strokes and their outline sit within a pixel of each other: group them with a 3x3 closing.
    grouped = cv2.dilate(candidate, _DISC3)
    n, labels = cv2.connectedComponents(grouped, connectivity=8)
    if n <= 1:
        return np.zeros_like(fov)
    strongest = np.zeros(n, np.int32)
    np.maximum.at(strongest, labels[candidate.astype(bool)], contrast[candidate.astype(bool)])
    keep = strongest >= TEXT_CONTRAST
    keep[0] = False
    text = keep[labels] & candidate.astype(bool)
    # One pixel of margin: the strokes' edges change a little under video compression.
    overlay: np.ndarray = cv2.dilate(text.astype(np.uint8), _SQUARE3).astype(bool) & fov
    return overlay


def detect_area(stats: BlockStats, previous: ContentArea | None = None) -> ContentArea:
    """The content area seen in one block; overlays the block cannot tell are taken from ``previous``."""
    if stats.high is None or stats.low is None:
        raise ValueError("no frames in the block")
    fov = detect_fov(stats.high, stats.low)
    if previous is not None and (
        fov is None or (fov.all() and not previous.fov.all() and is_dark_border(stats.high, stats.low, ~previous.fov))
    ):
        fov = previous.fov  # no evidence against the field of view in use (a dark moment, not a new scope)
    if fov is None:
        fov = np.ones(stats.high.shape, bool)
    overlay = detect_overlay(stats.high, stats.low, fov)
    if overlay is None:
        overlay = previous.overlay & fov if previous is not None else np.zeros_like(fov)
    return ContentArea(fov, overlay)


# ----------------------------------------------------------------------------------------------- the stream


class _Placement:
    """How one area turns a frame into the method's input and the method's output back into a frame."""

    def __init__(self, area: ContentArea) -> None:
        self.area = area
        x, y, w, h = area.box()
        self.rows, self.cols = slice(y, y + h), slice(x, x + w)
        inside = area.mask[self.rows, self.cols]
        self.inside_u8 = inside.astype(np.uint8)
        self.holes_u8 = (~inside).astype(np.uint8)  # in the box: pixels the method gets filled
        self.has_holes = bool(self.holes_u8.any())

    def method_input(self, frame: np.ndarray) -> np.ndarray:
        box = frame[self.rows, self.cols].copy()
        if self.has_holes:  # holes := the content's mean colour (cleared, then the mean added, both masked)
            mean = tuple(float(round(v)) for v in cv2.mean(box, mask=self.inside_u8)[:3]) + (0.0,)
            cv2.subtract(box, box, dst=box, mask=self.holes_u8)
            # ``mean`` is a Scalar, which cv2.add takes as src2; older stubs (opencv-python < 5.1) list arrays only
            cv2.add(box, mean, dst=box, mask=self.holes_u8)  # type: ignore[call-overload, unused-ignore]
        return box

    def output(self, frame: np.ndarray, enhanced_box: np.ndarray) -> np.ndarray:
        out = frame.copy()
        _copy_into(enhanced_box, self.inside_u8, out[self.rows, self.cols])
        return out


def _copy_into(src: np.ndarray, mask: np.ndarray, dst: np.ndarray) -> None:
    """``dst[mask] = src[mask]`` in place (``dst`` may be a view), at OpenCV's speed (10x numpy's ``where``)."""
    written = cv2.copyTo(src, mask, dst)
    if not np.shares_memory(written, dst):  # OpenCV gave a new array instead of writing through the view
        dst[...] = written


class ContentStream(MethodStream):
    """Any method's stream, shown only the content area (see the module docstring); a frame without a border
    or overlays goes to the method untouched, so its result is exactly the method's own."""

    def __init__(
        self,
        inner: MethodStream,
        detect_frames: int = DETECT_FRAMES,
        *,
        first_frames: int | None = None,
        resize: Literal["refuse", "redetect"] = "refuse",
        area: ContentArea | None = None,
        area_name: str = "the content area given",
    ) -> None:
        """``first_frames``: frames held back for the first decision (default ``detect_frames``). ``resize``: a
        frame of another size is refused (a clip has one size), or starts a new detection (a live source may
        reconnect at another size; the method's own stream, and its state, go on). ``area``: use this area for
        every frame and detect nothing (a scope's known mask, as a host is given it); frames must be its size, or
        fail naming ``area_name``."""
        first_frames = detect_frames if first_frames is None else first_frames
        if detect_frames < 1 or first_frames < 1:
            raise OptionError(f"detect_frames and first_frames must be >= 1, got {detect_frames}, {first_frames}")
        if area is not None and resize != "refuse":
            raise OptionError("a given content area fits one frame size: resize must be 'refuse'")
        self._fixed = area is not None
        self._area_name = area_name
        self._inner = inner
        self._detect_frames = detect_frames
        self._first_frames = first_frames
        self._resize = resize
        self._stats = BlockStats()
        self._placement: _Placement | None = None  # None until the first block is seen; then per area
        self._warmup: list[np.ndarray] = []
        self._in_flight: deque[tuple[np.ndarray, _Placement, dict[str, Any] | None]] = deque()
        self._candidate: ContentArea | None = None
        self._agreeing = 0
        self._announce: dict[str, Any] | None = None  # the area change recorded with the next frame
        self._placed = False  # an area has been in use (a new frame size then records the area it finds)
        if area is not None:
            self._use(area)

    @property
    def area(self) -> ContentArea | None:
        """The content area in use (``None`` before the first block is complete)."""
        return self._placement.area if self._placement is not None else None

    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        shape = (self._warmup[0] if self._warmup else self._placement.area.fov if self._placement else frame).shape
        if frame.shape[:2] != shape[:2]:
            if self._fixed:
                raise FrameShapeError(
                    f"frame is {frame.shape[1]}x{frame.shape[0]}, {self._area_name} is {shape[1]}x{shape[0]}"
                )
            if self._resize == "refuse" or self._warmup:
                raise FrameShapeError(
                    f"frame is {frame.shape[1]}x{frame.shape[0]}, the stream started at "
                    f"{shape[1]}x{shape[0]}: start a new stream for a new frame size"
                )
            # another picture layout: find its area afresh (frames in flight keep their own placement)
            self._stats, self._placement, self._candidate, self._agreeing = BlockStats(), None, None, 0
        if self._fixed:
            return self._send(frame)
        self._stats.add(frame)
        if self._placement is None:
            self._warmup.append(frame)
            if self._stats.count < self._first_frames:
                return []
            self._start()
            return self._drain_warmup()
        results = self._send(frame)
        if self._stats.count >= self._detect_frames:
            self._consider(detect_area(self._stats, self._placement.area))
            self._stats = BlockStats()
        return results

    def flush(self) -> list[FrameResult]:
        results: list[FrameResult] = []
        if self._placement is None and self._warmup:
            self._start()
            results += self._drain_warmup()
        results += self._finish(self._inner.flush())
        return results

    def _start(self) -> None:
        area = detect_area(self._stats)
        self._stats = BlockStats()
        self._use(area)

    def _drain_warmup(self) -> list[FrameResult]:
        frames, self._warmup = self._warmup, []
        results: list[FrameResult] = []
        for f in frames:
            results += self._send(f)
        return results

    def _use(self, area: ContentArea) -> None:
        # recorded when it changes the area in use, or when the first area is not the whole frame
        if self._placed or not area.is_full:
            self._announce = area.summary()
        self._placement, self._placed = _Placement(area), True

    def _consider(self, candidate: ContentArea) -> None:
        """Hysteresis: change the area only after ``CHANGE_BLOCKS`` agreeing candidates that differ from it."""
        assert self._placement is not None
        if candidate.same_as(self._placement.area):
            self._candidate, self._agreeing = None, 0
            return
        if self._candidate is not None and candidate.same_as(self._candidate):
            self._agreeing += 1
        else:
            self._candidate, self._agreeing = candidate, 1
        if self._agreeing >= CHANGE_BLOCKS:
            self._use(candidate)
            self._candidate, self._agreeing = None, 0

    def _send(self, frame: np.ndarray) -> list[FrameResult]:
        assert self._placement is not None
        placement, note = self._placement, self._announce
        self._announce = None
        self._in_flight.append((frame, placement, note))
        fed = frame if placement.area.is_full else placement.method_input(frame)
        return self._finish(self._inner.push(fed))

    def _finish(self, results: list[FrameResult]) -> list[FrameResult]:
        out: list[FrameResult] = []
        for res in results:
            frame, placement, note = self._in_flight.popleft()
            if not placement.area.is_full:
                res = dataclasses.replace(res, frame=placement.output(frame, res.frame))
            if note is not None:
                res = dataclasses.replace(res, info={**res.info, "content": note})
            out.append(res)
        return out


def content_stream(method: Method, mode: str = DEFAULT_CONTENT, *, live: bool = False) -> MethodStream:
    """A fresh stream of ``method`` for one clip, shown the content area (``auto``), the whole frame (``full``)
    or the area of a mask image (any other value: its path, read here, or :func:`parse_content`'s mask, whose
    area is used without reading the file again). ``live``: for a source that cannot wait,
    :func:`live_content_stream`."""
    inner = method.stream()
    word = parse_content(mode)
    if word == "full":
        return inner
    if isinstance(word, ContentMask):  # the area read once for the run, sent to worker processes with the options
        return ContentStream(inner, area=word.area, area_name=f"the content mask {word}")
    return ContentStream(inner, first_frames=LIVE_FIRST_FRAMES, resize="redetect") if live else ContentStream(inner)


@dataclass(frozen=True)
class FoundArea:
    """What :func:`find_content_area` saw: the area in use after the last frame, and where it changed."""

    area: ContentArea
    frames: int  # frames looked at
    changes: tuple[int, ...]  # frames from which a new area was in use (after the first)


def find_content_area(frames: Iterable[np.ndarray], source: object = "the frames") -> FoundArea:
    """The content area ``colonlight enhance`` uses on ``frames`` (``--content auto``), found exactly as it finds
    it: its stream run over the frames with a method that changes nothing. ``InputError`` naming ``source`` if
    there is no frame."""
    stream = ContentStream(create_method("none").stream())
    count, changes = 0, []
    for results in _pushed(stream, frames):
        for res in results:
            if "content" in res.info and count > 0:
                changes.append(count)
            count += 1
    if stream.area is None:
        raise InputError(f"{source}: no frames to find a content area in")
    return FoundArea(stream.area, count, tuple(changes))


def _pushed(stream: ContentStream, frames: Iterable[np.ndarray]) -> Iterator[list[FrameResult]]:
    """Each frame's results, then the stream's flush."""
    for frame in frames:
        yield stream.push(frame)
    yield stream.flush()


def live_content_stream(method: Method, mode: str = DEFAULT_CONTENT) -> MethodStream:
    """:func:`content_stream` for a live source (``colonlight stream``, the service's WebSocket): the first area
    is found on the first frame, so no frame waits, and a change of frame size finds the area again."""
    return content_stream(method, mode, live=True)


__all__ = [
    "CONTENT_MODES",
    "DEFAULT_CONTENT",
    "ContentArea",
    "ContentMode",
    "ContentStream",
    "FoundArea",
    "content_setting",
    "content_stream",
    "find_content_area",
    "live_content_stream",
    "detect_area",
    "detect_fov",
    "detect_overlay",
    "iou",
    "parse_content",
    "parse_content_mode",
]
