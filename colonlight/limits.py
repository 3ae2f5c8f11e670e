"""Bounds on what one clip may ask of a machine, and the defaults they bound, shared by the CLI and the service
(one place for each).

A frame of ``w x h`` pixels costs ``3 w h`` bytes as RGB and about as much again while it is decoded, resized and
encoded, so the pixel cap bounds memory per frame whatever the input claims to be; the fps cap bounds how many
output frames one second of input can become, and the gap cap how many copies of one frame a timestamp gap can
become (the copies stream one at a time, so the cap bounds time and disk, not memory).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Final

#: Largest frame accepted (width x height), checked from the stream header before any frame is decoded.
#: 4096 x 4096 admits UHD and DCI 4K video (8.3 and 8.8 Mpx) with room to spare; an 8000 x 8000 "bomb" is refused.
DEFAULT_MAX_PIXELS = 4096 * 4096
#: Highest extraction rate accepted (frames per second of output); 0 means "every source frame".
MAX_FPS = 240.0
#: Lowest extraction rate above 0 accepted: frame rates are exact ratios with a denominator of at most 1001
#: (NTSC), so a lower one would round to 0 frames per second.
MIN_FPS = 1 / 1001


def is_usable_fps(fps: float) -> bool:
    """Whether ``fps`` is an extraction rate colonlight accepts: 0 (every source frame), or ``MIN_FPS`` up to
    ``MAX_FPS`` (NaN is not)."""
    return 0 <= fps <= MAX_FPS and (fps == 0 or fps >= MIN_FPS)


#: Longest side of ``enhanced.mp4`` (after padding odd sides to even): x264 refuses a larger frame, which a frame
#: within the pixel cap can have (2 x 30000 is 0.06 Mpx).
MAX_VIDEO_SIDE = 16384
#: Environment variable that overrides :data:`DEFAULT_MAX_PIXELS` in the CLI and the service alike.
MAX_PIXELS_ENV = "COLONLIGHT_MAX_PIXELS"
#: Most copies of one source frame that the fps conversion may add for a timestamp gap (the frame repeated
#: until the next one is due, as ``ffmpeg -vf fps=18`` repeats it): 10 minutes at 18 fps. A clip past it fails
#: with one line; MPEG-TS/PS jumps of more than 10 s are bridged before this (as ffmpeg bridges them).
DEFAULT_MAX_GAP_FRAMES = 10 * 60 * 18
#: Environment variable that overrides :data:`DEFAULT_MAX_GAP_FRAMES` in the CLI and the service alike.
MAX_GAP_FRAMES_ENV = "COLONLIGHT_MAX_GAP_FRAMES"
#: The extraction rate when none is given (CLI, service, evaluation, training, a frame folder's assumed rate):
#: the authors' ``ffmpeg -vf fps=18`` extraction, which their model was trained on.
DEFAULT_FPS = 18.0
#: The method when none is given (``--method``, the service's ``COLONLIGHT_METHOD``, the Python API): the paper's model.
DEFAULT_METHOD = "rnn"
#: The image format of a clip's enhanced frames when none is given (``enhance --format``, a job's ``format``); a live
#: stream's default differs (``jpg``: at 1080p a PNG costs too much CPU for real time).
DEFAULT_FRAME_FORMAT: Final = "png"  # Final: typed as the literal, which the requests' Literal["png", "jpg"] needs
#: JPEG quality of enhanced frames when none is given (``--quality``, a request's ``quality``), and its range.
DEFAULT_JPEG_QUALITY = 95
MIN_JPEG_QUALITY, MAX_JPEG_QUALITY = 1, 100
#: The rnn method's network input side in pixels (``--model-size``, a request's ``model_size``): below 8 the
#: encoder's strides leave nothing; above 1024 a step costs seconds on a CPU while ``full`` covers that need.
MIN_MODEL_SIZE, MAX_MODEL_SIZE = 8, 1024
#: The rnn method's input side when neither the option nor the weights' card gives one, and the size ``colonlight
#: train`` trains at. Chosen by measurement (README, "Choosing the network input size").
DEFAULT_MODEL_SIZE = 48
#: Largest training seed (``colonlight train --seed``): NumPy's global generator, which a run seeds for
#: reproducibility, takes 0..2**32 - 1 and raised a traceback for anything else.
MAX_TRAIN_SEED = 2**32 - 1
#: Largest learning rate a run takes (``--lr``): near 1e37 Adam's step overflowed float32 inside the optimizer (a
#: traceback); up to this, a rate too high for the run ends in one line as a divergence (``try a lower --lr``).
MAX_LEARNING_RATE = 1e30
#: Largest exponent of the ``gamma`` method (``out = in ** gamma``): at 10 all but the brightest pixels are black
#: already, so a larger value is a typo.
MAX_GAMMA = 10.0


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity, e.g. a container's cpuset), at least 1."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _positive_setting(name: str, default: int, unit: str, environ: Mapping[str, str] | None) -> int:
    raw = (os.environ if environ is None else environ).get(name, "").strip()
    if not raw:
        return default
    try:
        value = int(raw)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"{name} must be a positive whole number of {unit}, got {raw!r}")
    return value


def max_pixels_setting(environ: Mapping[str, str] | None = None) -> int:
    """The pixel cap in force: :data:`MAX_PIXELS_ENV` if set, else :data:`DEFAULT_MAX_PIXELS`.

    ValueError (naming the variable) if the variable is set to anything but a positive integer.
    """
    return _positive_setting(MAX_PIXELS_ENV, DEFAULT_MAX_PIXELS, "pixels", environ)


def max_gap_frames_setting(environ: Mapping[str, str] | None = None) -> int:
    """The cap on a gap's repeated frames: :data:`MAX_GAP_FRAMES_ENV` if set, else :data:`DEFAULT_MAX_GAP_FRAMES`.

    ValueError (naming the variable) if the variable is set to anything but a positive integer.
    """
    return _positive_setting(MAX_GAP_FRAMES_ENV, DEFAULT_MAX_GAP_FRAMES, "frames", environ)
