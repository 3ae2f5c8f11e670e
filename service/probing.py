"""Checking an upload before it is admitted: frames within the pixel cap (413), and a video at all (415)."""

from __future__ import annotations

import anyio

from colonlight import ColonlightError, VideoInfo, probe_video

from .errors import ApiError
from .header_probe import declared_frame_size
from .metrics import Metrics
from .settings import Settings
from .uploads import Upload
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
