"""What a real scope's video processor adds to the picture: a black border around the field of view (round or
octagonal) and fixed on-screen text (patient fields, time, scope settings).

Drawn onto the recorded frames (and the clean ones, which the same processor would frame alike) so that the
content-area detection (:mod:`colonlight.content`) can be tested against a known truth: :meth:`OverlaySpec.masks`
gives the field of view and the text pixels exactly as drawn. Text is keyed opaque, as a character generator
does: every text pixel has the same value in every frame (before video compression).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

import cv2
import numpy as np

Border = Literal["none", "round", "octagon"]
BORDERS: tuple[str, ...] = ("none", "round", "octagon")
#: Grey level of the border and of the text's outline; real processors output black (about 0 after decoding).
BORDER_LEVEL = 0
TEXT_COLOUR = (235, 235, 235)
#: The on-screen text: patient fields at the top left, time at the top right, scope settings at the bottom.
TEXT_LINES = (
    ("ID 0042-17", "top-left"),
    ("F 63y", "top-left-2"),
    ("10:24:37", "top-right"),
    ("Ex A2 E3", "bottom"),
)


@dataclass(frozen=True)
class OverlaySpec:
    """Border and text drawn onto every frame of a clip.

    Attributes:
        border: ``none``, ``round`` (a disc) or ``octagon`` (a rectangle with cut corners).
        fov: the field of view's height as a share of the frame height (a disc's diameter; the octagon's
            height, its width being ``fov * width``).
        text: draw the fixed text lines (``TEXT_LINES``).
    """

    border: Border = "none"
    fov: float = 0.96
    text: bool = False

    def __post_init__(self) -> None:
        if self.border not in BORDERS:
            raise ValueError(f"border must be one of {', '.join(BORDERS)}, got {self.border!r}")
        if not 0.3 <= self.fov <= 1.0:
            raise ValueError(f"fov must be within 0.3..1.0, got {self.fov}")

    @property
    def active(self) -> bool:
        """True if anything is drawn."""
        return self.border != "none" or self.text

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def masks(self, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
        """``(fov, text)``: ``(H, W)`` bool masks of the field of view and of the text (outline included)."""
        text = text_mask(height, width) if self.text else np.zeros((height, width), bool)
        return fov_mask(height, width, self.border, self.fov), text

    def apply(self, frame: np.ndarray) -> np.ndarray:
        """``frame`` with the border and the text drawn (a new array)."""
        h, w = frame.shape[:2]
        fov, text = self.masks(h, w)
        out = frame.copy()
        out[~fov] = BORDER_LEVEL
        if self.text:
            out[text] = BORDER_LEVEL
            out[_text_core(h, w)] = TEXT_COLOUR
        return out


def drawn_overlay(overlay: OverlaySpec | None) -> OverlaySpec | None:
    """``overlay`` if it draws anything, else None: the one test of whether a clip has an overlay (its frames,
    its ``content.png`` and its manifest all follow it)."""
    return overlay if overlay is not None and overlay.active else None


def fov_mask(height: int, width: int, border: str, fov: float = 0.96) -> np.ndarray:
    """``(H, W)`` bool, True inside the field of view (all True for ``border="none"``)."""
    if border == "none":
        return np.ones((height, width), bool)
    canvas = np.zeros((height, width), np.uint8)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    if border == "round":
        r = fov * height / 2
        cv2.circle(canvas, (round(cx * 16), round(cy * 16)), round(r * 16), 1, thickness=-1, shift=4)
    else:
        hw, hh = fov * width / 2, fov * height / 2
        cut = 0.3 * min(hw, hh)  # corner cut: a regular-looking octagon on a 4:3 frame
        pts = [
            (-hw + cut, -hh),
            (hw - cut, -hh),
            (hw, -hh + cut),
            (hw, hh - cut),
            (hw - cut, hh),
            (-hw + cut, hh),
            (-hw, hh - cut),
            (-hw, -hh + cut),
        ]
        poly = np.array([[round((cx + x) * 16), round((cy + y) * 16)] for x, y in pts], np.int32)
        cv2.fillConvexPoly(canvas, poly, 1, shift=4)
    return canvas.astype(bool)


def _text_canvas(height: int, width: int, thickness: int) -> np.ndarray:
    scale = max(0.3, height / 720)
    canvas = np.zeros((height, width), np.uint8)
    margin = max(2, height // 60)
    for line, where in TEXT_LINES:
        (tw, th), _ = cv2.getTextSize(line, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        x, y = margin, margin + th
        if where == "top-left-2":
            y += th + 2 * margin
        elif where == "top-right":
            x = width - margin - tw
        elif where == "bottom":
            x, y = (width - tw) // 2, height - 5 * margin
        cv2.putText(canvas, line, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, 255, thickness, cv2.LINE_8)
    return canvas


def _text_core(height: int, width: int) -> np.ndarray:
    return _text_canvas(height, width, 1) > 0


def text_mask(height: int, width: int) -> np.ndarray:
    """``(H, W)`` bool: the text's pixels, with a 1-pixel dark outline around the strokes (as OSD text has)."""
    core = _text_canvas(height, width, 1)
    return cv2.dilate(core, np.ones((3, 3), np.uint8)) > 0
