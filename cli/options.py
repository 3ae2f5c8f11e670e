"""Options shared by several commands (same names, help and environment variables everywhere)."""

from __future__ import annotations

from pathlib import Path

import typer

from colonlight.limits import DEFAULT_MAX_GAP_FRAMES, DEFAULT_MAX_PIXELS, MAX_FPS, MAX_GAP_FRAMES_ENV, MAX_PIXELS_ENV

Device = typer.Option("auto", "--device", envvar="COLONLIGHT_DEVICE", help="auto | cpu | cuda | cuda:N.")
Method = typer.Option(
    "rnn", "--method", "-m", envvar="COLONLIGHT_METHOD", help="Enhancement method (see `colonlight info`)."
)
Weights: Path | None = typer.Option(
    None,
    "--weights",
    "-w",
    envvar="COLONLIGHT_WEIGHTS",
    help="Checkpoint: ours (.safetensors with its .json card) or the authors' .pth. Default: the shipped model.",
)
ModelSize = typer.Option(
    None,
    "--model-size",
    envvar="COLONLIGHT_MODEL_SIZE",
    help="Network input size in pixels, 'full' for full-resolution input (the release's way), or 'auto' (the "
    "default): the size the weights were trained at (their card; 48 for the shipped model), else 48.",
)
Runtime = typer.Option(
    "torch",
    "--runtime",
    envvar="COLONLIGHT_RUNTIME",
    help="Where the rnn method's network step runs: torch, or onnxruntime (CPU; the export extra; measured faster "
    "on small CPUs, see the README's benchmarks).",
)
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
Content = typer.Option(
    "auto",
    "--content",
    envvar="COLONLIGHT_CONTENT",
    help="auto: find the field of view inside a black border and fixed on-screen text, let the method see only "
    "them and write border and text pixels unchanged (a frame without either is processed as with full); "
    "full: the whole frame.",
)
Debug = typer.Option(False, "--debug", envvar="COLONLIGHT_DEBUG", help="Show tracebacks of errors.")
Quiet = typer.Option(
    False, "--quiet", "-q", envvar="COLONLIGHT_QUIET", help="No live display: one line per clip, for logs."
)


def method_options(
    method: str,
    weights: Path | None,
    model_size: str | None,
    device: str,
    gamma: float | None = None,
    runtime: str | None = None,
) -> dict[str, object]:
    """The keyword options of ``method`` from the CLI's flags (flags a method does not take are refused)."""
    opts: dict[str, object] = {}
    if method in ("rnn", "zerodce", "zerodce++"):
        opts["device"] = device
        if weights is not None:
            opts["weights"] = str(weights)
    elif weights is not None:
        raise typer.BadParameter(f"--weights does not apply to method {method!r}")
    if method == "rnn" and model_size is not None:
        opts["model_size"] = model_size
    elif model_size is not None:
        raise typer.BadParameter(f"--model-size does not apply to method {method!r}")
    if runtime not in (None, "torch", "onnxruntime"):
        raise typer.BadParameter(f"choose torch or onnxruntime, got {runtime!r}", param_hint="--runtime")
    if method == "rnn" and runtime == "onnxruntime":
        opts["runtime"] = runtime
    elif runtime == "onnxruntime":
        raise typer.BadParameter("--runtime onnxruntime applies only to --method rnn")
    if method == "gamma" and gamma is not None:
        opts["gamma"] = gamma
    elif gamma is not None:
        raise typer.BadParameter("--gamma applies only to --method gamma")
    return opts


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
    """A usage error unless ``0 <= fps <= MAX_FPS`` (the service's bound too)."""
    if not 0 <= fps <= MAX_FPS:
        raise typer.BadParameter(
            f"must be within 0..{MAX_FPS:g} frames per second (0 keeps every frame), got {fps:g}", param_hint="--fps"
        )
