"""Which video stream of a file is "the" clip: the one the ``ffmpeg`` tool takes when no ``-map`` is given.

A recording may hold more than one video stream (a scope's full picture and a small preview, two camera
angles) and cover art. libavformat's ``av_find_best_stream`` ranks them by bit rate and frame count, so a small
preview with a higher bit rate won over the picture itself; ``ffmpeg -i in.mp4 -vf fps=18 out%d.png``, which the
frame choice is checked against, takes the stream of the most pixels instead (``fftools/ffmpeg_mux_init.c``,
``map_auto_video``): width x height, plus a bonus of 5,000,000 for a stream marked default; the first stream
wins a tie; cover art (an attached picture) is never a clip's video.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import av

_DEFAULT_BONUS = 5_000_000  # ffmpeg's weight of the "default" disposition, in pixels


def _score(stream: Any) -> int:
    ctx = stream.codec_context
    pixels = int(ctx.width or 0) * int(ctx.height or 0) if ctx is not None else 0
    return pixels + _DEFAULT_BONUS * bool(stream.disposition & av.stream.Disposition.default)


def main_video_stream(streams: Iterable[Any]) -> Any | None:
    """The video stream ``ffmpeg`` maps by default among ``streams`` (a container's ``streams.video``), cover
    art left out; None if there is none."""
    candidates = [s for s in streams if not s.disposition & av.stream.Disposition.attached_pic]
    if not candidates:
        return None
    return max(candidates, key=_score)  # max() keeps the first of equal scores, as ffmpeg does
