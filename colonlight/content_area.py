"""Where a scope's picture shows the scene: the field of view and the fixed text inside it, as masks.

Its own module so that what finds an area (:mod:`colonlight.content`, from the frames) and what reads and writes
one (:mod:`colonlight.content_mask`, as an image a host is given) share it without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

#: Areas whose fields of view overlap this much (IoU) and whose overlays differ by at most ``OVERLAY_SLACK`` of
#: their pixels (or 16 pixels) are the same area.
SAME_IOU = 0.98
OVERLAY_SLACK = 0.1


@dataclass(frozen=True, eq=False)
class ContentArea:
    """Where the scene is: ``fov`` (field of view) and ``overlay`` (fixed text inside it), ``(H, W)`` bool."""

    fov: npt.NDArray[np.bool_]
    overlay: npt.NDArray[np.bool_]

    @staticmethod
    def full(height: int, width: int) -> ContentArea:
        return ContentArea(np.ones((height, width), bool), np.zeros((height, width), bool))

    @property
    def is_full(self) -> bool:
        """True if every pixel is content: the method then sees the frame itself."""
        return bool(self.fov.all()) and not bool(self.overlay.any())

    @property
    def mask(self) -> np.ndarray:
        """``(H, W)`` bool: content pixels (inside the field of view, not overlay)."""
        return self.fov & ~self.overlay

    def box(self) -> tuple[int, int, int, int]:
        """``(x, y, w, h)`` of the field of view's bounding box."""
        x, y, w, h = cv2.boundingRect(self.fov.astype(np.uint8))
        return int(x), int(y), int(w), int(h)

    def summary(self) -> dict[str, Any]:
        """What is recorded in ``gammas.json`` when the area changes."""
        if self.is_full:
            return {"full": True}
        return {
            "box": list(self.box()),
            "fov_fraction": round(float(self.fov.mean()), 4),
            "overlay_pixels": int(self.overlay.sum()),
        }

    def same_as(self, other: ContentArea) -> bool:
        """True if the two areas are close enough that switching would change nothing worth a switch."""
        if self.fov.shape != other.fov.shape or iou(self.fov, other.fov) < SAME_IOU:
            return False
        differ = int(np.count_nonzero(self.overlay ^ other.overlay))
        return differ <= max(16, OVERLAY_SLACK * max(int(self.overlay.sum()), int(other.overlay.sum())))


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two bool masks (1.0 for two empty masks)."""
    union = int(np.count_nonzero(a | b))
    return 1.0 if union == 0 else int(np.count_nonzero(a & b)) / union
