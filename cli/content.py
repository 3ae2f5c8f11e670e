"""``colonlight content``: a clip's content area (field of view, fixed text) as a mask image for a host."""

from __future__ import annotations

import itertools
import math
import sys
from pathlib import Path

import typer

from colonlight.limits import DEFAULT_FPS

from . import options
from .display import console, printable
from .failures import FAILED, ends_command
from .interrupts import interruptible


def content(
    clip: Path = typer.Argument(..., help="A video file or a folder of frames."),
    output: Path = typer.Option(..., "--output", "-o", help="The mask to write: .pgm (the C++ host's) or .png."),
    seconds: float = typer.Option(
        10.0,
        "--seconds",
        min=0.0,
        help="Look at the clip's first SECONDS (at the enhance default of 18 fps); 0: the whole clip.",
    ),
    debug: bool = options.Debug,
) -> None:
    """Write the content area `colonlight enhance` finds on CLIP (255 scene, 128 fixed text, 0 border) as a mask
    for a host that is given it instead of finding it (`colonlight_host --content MASK.pgm`)."""
    # imported here: `colonlight --help` and the other commands do not load OpenCV and the methods for this one
    from colonlight import (
        OptionError,
        OutputError,
        check_mask_output,
        clip_frames,
        find_content_area,
        write_content_mask,
    )

    try:
        check_mask_output(output, clip)
    except OptionError as exc:  # before the clip is read
        raise typer.BadParameter(str(exc), param_hint="--output") from None
    if not math.isfinite(seconds):
        raise typer.BadParameter(f"must be a number of seconds, got {seconds}", param_hint="--seconds")
    with ends_command(FAILED, debug):
        frames = (f.image for f in clip_frames(clip, fps=DEFAULT_FPS))
        # capped: 1e300 seconds is as many frames as the clip has, not an overflow
        limit = max(1, math.ceil(min(seconds * DEFAULT_FPS, sys.maxsize))) if seconds > 0 else None
        found = find_content_area(itertools.islice(frames, limit), clip)
        try:
            write_content_mask(output, found.area)
        except OSError as exc:  # a missing folder, a read-only disk: the output named, one line
            raise OutputError(f"{output}: cannot write ({exc.strerror or exc})") from exc
    summary = found.area.summary()
    if summary.get("full"):
        described = "no border or fixed text found: every pixel is scene"
    else:
        x, y, w, h = summary["box"]
        described = f"box {w}x{h} at ({x}, {y}), field of view {summary['fov_fraction']:.0%}"
        described += f", {summary['overlay_pixels']} text pixels"
    console.print(
        f"{printable(str(clip))}: {described} ({found.frames} frame{'' if found.frames == 1 else 's'})", soft_wrap=True
    )
    if found.changes:
        at = ", ".join(str(i) for i in found.changes)
        console.print(f"the area changed at frame {at}; the mask is the one in use at the last frame")
    console.print(f"wrote {printable(str(output))}", soft_wrap=True)


def register(app: typer.Typer) -> None:
    app.command("content")(interruptible(content))  # SIGTERM as Ctrl-C: temporaries removed, exit 143
