"""Checking an upload before it is admitted: frames within the pixel cap (413), a video at all (415), and its
content mask, if one came with it, a mask the engine reads (422, 413 over the pixel cap)."""

from __future__ import annotations

import anyio

from colonlight import ColonlightError, VideoInfo, load_content_mask, probe_video
from colonlight.errors import FrameTooLargeError

from .errors import ApiError
from .header_probe import declared_frame_size
from .metrics import Metrics
from .settings import Settings
from .uploads import MaskUpload, Upload
from .workspace import Workspace


class UploadProbe:
    """Opens uploads a few at a time: probing one opens a decoder (threads, frame buffers), so memory does not grow
    with the number of clients uploading at once. ``limiter`` bounds the other decoder openings of an upload too
    (counting its frames when it becomes a job)."""

    def __init__(self, settings: Settings, metrics: Metrics, workspace: Workspace) -> None:
        self.settings = settings
        self.metrics = metrics
        self.workspace = workspace
        self.limiter = anyio.CapacityLimiter(max(2, settings.workers))

    async def probe(self, upload: Upload) -> VideoInfo:
        """413 if the frames are over the pixel cap (read from the stream header, before any frame is decoded),
        415 unless the upload decodes as video."""
        cap = self.settings.max_pixels
        declared = await anyio.to_thread.run_sync(declared_frame_size, upload.path, cap, limiter=self.limiter)
        if declared is not None:
            self._check_pixels(upload, *declared)
        try:
            info = await anyio.to_thread.run_sync(probe_video, upload.path, limiter=self.limiter)
        except ColonlightError as exc:
            self.metrics.inc("rejected", "not_video")
            message = self.workspace.scrub(str(exc), upload.path, upload.filename)
            raise ApiError(415, "unsupported_media_type", message) from None
        self._check_pixels(upload, info.width, info.height)  # a header that said nothing, or too little
        return info

    def _check_pixels(self, upload: Upload, width: int, height: int) -> None:
        cap = self.settings.max_pixels
        if width * height > cap:
            self.metrics.inc("rejected", "too_many_pixels")
            raise ApiError(
                413,
                "frame_too_large",
                f"{upload.filename}: its frames are {width}x{height} ({width * height} pixels), over this "
                f"server's limit of {cap} pixels a frame (COLONLIGHT_MAX_PIXELS)",
            )

    async def check_mask(self, upload: Upload) -> None:
        """Read the upload's content mask as the engine will (:func:`colonlight.load_content_mask`: JPEG, lossy
        WebP, damaged PGM, colour or scene-less images are refused) and keep its SHA-256 on ``upload.mask``, the
        hash the job records. 422 (413 over the pixel cap) with one line naming the mask by its upload name."""
        mask = upload.mask
        if mask is None:
            return
        try:
            loaded = await anyio.to_thread.run_sync(load_content_mask, mask.path, limiter=self.limiter)
        except FrameTooLargeError as exc:
            self.metrics.inc("rejected", "too_many_pixels")
            raise self._mask_too_large(mask, exc.width, exc.height) from None
        except ColonlightError as exc:
            self.metrics.inc("rejected", "bad_content_mask")
            message = self.workspace.scrub(str(exc), mask.path, mask.filename)
            raise ApiError(422, "invalid_content_mask", f"content mask {message}") from None
        height, width = loaded.area.fov.shape
        if width * height > self.settings.max_pixels:
            self.metrics.inc("rejected", "too_many_pixels")
            raise self._mask_too_large(mask, width, height)
        mask.sha256 = loaded.sha256

    def _mask_too_large(self, mask: MaskUpload, width: int, height: int) -> ApiError:
        return ApiError(
            413,
            "frame_too_large",
            f"content mask {mask.filename}: it is {width}x{height} ({width * height} pixels), over this server's "
            f"limit of {self.settings.max_pixels} pixels a frame (COLONLIGHT_MAX_PIXELS)",
        )
