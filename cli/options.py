"""Options shared by several commands (same names, help and environment variables everywhere).

The method options (``--weights``, ``--model-size``, ``--gamma``, ``--device``, ``--runtime``) are built from
the methods' one declaration, :mod:`colonlight.methods.options`, as the service's request fields are.
"""

from __future__ import annotations

from typing import Any

import typer

from colonlight import METHOD_NAMES, method_problem
from colonlight.errors import ColonlightError, MethodOptionError
from colonlight.limits import (
    DEFAULT_MAX_GAP_FRAMES,
    DEFAULT_MAX_PIXELS,
    DEFAULT_METHOD,
    MAX_FPS,
    MAX_GAP_FRAMES_ENV,
    MAX_PIXELS_ENV,
    is_usable_fps,
)
from colonlight.methods.options import OPTIONS, methods_kwargs, option

Method = typer.Option(
    DEFAULT_METHOD, "--method", "-m", envvar="COLONLIGHT_METHOD", help="Enhancement method (see `colonlight info`)."
)
#: Short flags of method options (the declaration names the long ones).
_SHORT = {"weights": ("-w",)}
_METAVAR = {"number": "NUMBER", "size": "PIXELS|full|auto", "path": "FILE"}


def method_flag(name: str) -> Any:
    """The typer option of the declared method option ``name`` (:mod:`colonlight.methods.options`): its flag,
    environment variable and help come from the declaration, and so does the check of its value, so that a bad
    value is refused with the service's message. Its value (canonical, e.g. a float for ``--gamma``) reaches a
    command through :func:`method_kwargs`, which also refuses a flag the method does not take."""
    opt = option(name)

    def check(value: str | None) -> object:
        if value is None:
            return None
        try:
            return opt.parse(value)
        except MethodOptionError as exc:
            raise typer.BadParameter(str(exc)) from None

    return typer.Option(
        None,
        opt.flag,
        *_SHORT.get(name, ()),
        envvar=opt.envvar,
        help=opt.description,
        metavar=_METAVAR.get(opt.kind, "|".join(opt.choices) or opt.name.upper()),
        callback=check,
        show_default=False,
    )


Weights = method_flag("weights")
ModelSize = method_flag("model_size")
Gamma = method_flag("gamma")
ToneMatch = method_flag("tone_match")
SceneCut = method_flag("scene_cut")
Device = method_flag("device")
Runtime = method_flag("runtime")


def method_kwargs(ctx: typer.Context, *methods: str) -> dict[str, dict[str, object]]:
    """Each of ``methods``' keyword options from the command's method flags: a flag on the command line that
    none of them takes is a usage error; a value from the environment (``COLONLIGHT_GAMMA``) is used where it
    applies and ignored elsewhere."""
    given: dict[str, object] = {}
    fallback: dict[str, object] = {}
    for opt in OPTIONS:
        if opt.name in ctx.params:
            from_line = getattr(ctx.get_parameter_source(opt.name), "name", None) == "COMMANDLINE"
            (given if from_line else fallback)[opt.name] = ctx.params[opt.name]
    try:
        return {name: dict(kwargs) for name, kwargs in methods_kwargs(methods, given, fallback).items()}
    except MethodOptionError as exc:
        raise typer.BadParameter(str(exc), param_hint=option(exc.option).flag) from None


MaxPixels = typer.Option(
    DEFAULT_MAX_PIXELS,
    "--max-pixels",
    envvar=MAX_PIXELS_ENV,
    min=1,
    help="Largest frame (width x height) a clip may have; larger clips fail from their header, before decoding.",
)
MaxGapFrames = typer.Option(
    DEFAULT_MAX_GAP_FRAMES,
    "--max-gap-frames",
    envvar=MAX_GAP_FRAMES_ENV,
    min=1,
    help="Most copies of one frame a timestamp gap may add (the fps conversion repeats a frame until the next is "
    "due); a clip past it fails. Default: 10 minutes at 18 fps.",
)
#: Largest side of a rendered synthetic clip (`synth`, `train --synthetic-size`): a 4096 x 4096 frame is the
#: pixel cap `enhance` reads by default.
MAX_RENDER_SIDE = 4096
Content = typer.Option(
    "auto",
    "--content",
    envvar="COLONLIGHT_CONTENT",
    help="auto: find the field of view inside a black border and fixed on-screen text, let the method see only "
    "them and write border and text pixels unchanged (a frame without either is processed as with full); "
    "full: the whole frame; or a mask image (`colonlight content`'s, or drawn: 255 scene, 0 border) used for "
    "every frame.",
)
#: The help of the synthetic clip mix, for ``synth --steady`` and ``train --synthetic-steady`` alike.
_MIX_HELP = {
    "steady": "Fraction of synthetic clips with steady lighting (to be left alone).",
    "occluders": "Fraction of synthetic clips forced to have a close-occluder moment (otherwise each clip has one by "
    "chance, 35%).",
    "clean-seeds": "Fraction of synthetic clips whose first two frames are undisturbed.",
}


def clip_mix(kind: str, flag: str, default: float) -> Any:
    """The option of one share of the synthetic clip mix (``steady``, ``occluders`` or ``clean-seeds``): the
    same meaning whether ``synth`` renders the clips or ``train`` renders them for itself."""
    return typer.Option(default, flag, min=0.0, max=1.0, help=_MIX_HELP[kind])


Debug = typer.Option(False, "--debug", envvar="COLONLIGHT_DEBUG", help="Show tracebacks of errors.")
Quiet = typer.Option(
    False, "--quiet", "-q", envvar="COLONLIGHT_QUIET", help="No live display: one line per clip, for logs."
)


def invocation(ctx: typer.Context) -> str:
    """The command line that reproduces this call: the options given (on the line or by environment), in order."""
    import shlex

    words = ["colonlight", ctx.info_name or ""]
    for param in ctx.command.params:
        source = ctx.get_parameter_source(param.name or "")
        if getattr(source, "name", None) not in ("COMMANDLINE", "ENVIRONMENT"):
            continue
        value = ctx.params.get(param.name or "")
        values = value if isinstance(value, (list, tuple)) else [value]
        if not param.opts[0].startswith("-"):  # arguments
            words += [str(v) for v in values]
        elif getattr(param, "is_flag", False):
            words.append(param.opts[0] if value else (param.secondary_opts or [param.opts[0]])[0])
        else:
            for v in values:
                words += [param.opts[0], str(v)]
    return " ".join(shlex.quote(w) for w in words)


def check_fps(fps: float) -> None:
    """A usage error unless ``0 <= fps <= MAX_FPS`` (the service's bound too) and ``fps`` is 0 or at least
    ``MIN_FPS`` (1/1001: a lower rate rounds to 0 frames per second)."""
    if not is_usable_fps(fps):
        raise typer.BadParameter(
            f"must be within 0..{MAX_FPS:g} frames per second (0 keeps every frame; else at least 1/1001), got {fps:g}",
            param_hint="--fps",
        )


def check_method(method: str) -> None:
    """--method: an unknown name is a usage error; a known one whose implementation does not load here (torch under
    a memory limit) is a failure, exit 1, saying why. Imports that method only (all of them to list them)."""
    problem = method_problem(method)
    if problem is None:
        return
    if method not in METHOD_NAMES:
        raise typer.BadParameter(problem, param_hint="--method")
    raise ColonlightError(problem)
