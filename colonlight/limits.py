"""Bounds on what one clip may ask of a machine, and the defaults they bound, shared by the CLI and the service
(one place for each).

A frame of ``w x h`` pixels costs ``3 w h`` bytes as RGB and about as much again while it is decoded, resized and
encoded, so the pixel cap bounds memory per frame whatever the input claims to be; the fps cap bounds how many
output frames one second of input can become.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

#: Largest frame accepted (width x height), checked from the stream header before any frame is decoded.
#: 4096 x 4096 admits UHD and DCI 4K video (8.3 and 8.8 Mpx) with room to spare; an 8000 x 8000 "bomb" is refused.
DEFAULT_MAX_PIXELS = 4096 * 4096
#: Highest extraction rate accepted (frames per second of output); 0 means "every source frame".
MAX_FPS = 240.0
#: Environment variable that overrides :data:`DEFAULT_MAX_PIXELS` in the CLI and the service alike.
MAX_PIXELS_ENV = "COLONLIGHT_MAX_PIXELS"
#: The extraction rate when none is given (CLI, service, evaluation, training, a frame folder's assumed rate):
#: the authors' ``ffmpeg -vf fps=18`` extraction, which their model was trained on.
DEFAULT_FPS = 18.0
#: The rnn method's network input side in pixels (``--model-size``, a request's ``model_size``): below 8 the
#: encoder's strides leave nothing; above 1024 a step costs seconds on a CPU while ``full`` covers that need.
MIN_MODEL_SIZE, MAX_MODEL_SIZE = 8, 1024
#: Largest exponent of the ``gamma`` method (``out = in ** gamma``): at 10 all but the brightest pixels are black
#: already, so a larger value is a typo.
MAX_GAMMA = 10.0


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity, e.g. a container's cpuset), at least 1."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def max_pixels_setting(environ: Mapping[str, str] | None = None) -> int:
    """The pixel cap in force: :data:`MAX_PIXELS_ENV` if set, else :data:`DEFAULT_MAX_PIXELS`.

    ValueError (naming the variable) if the variable is set to anything but a positive integer.
    """
    raw = (os.environ if environ is None else environ).get(MAX_PIXELS_ENV, "").strip()
    if not raw:
        return DEFAULT_MAX_PIXELS
    try:
        value = int(raw)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"{MAX_PIXELS_ENV} must be a positive whole number of pixels, got {raw!r}")
    return value
