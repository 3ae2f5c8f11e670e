"""Options shared by several commands (same names, help and environment variables everywhere)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

Device = typer.Option("auto", "--device", envvar="COLONLIGHT_DEVICE", help="auto | cpu | cuda | cuda:N.")
Method = typer.Option("rnn", "--method", "-m", envvar="COLONLIGHT_METHOD", help="Enhancement method (see `colonlight info`).")
Weights: Optional[Path] = typer.Option(
    None, "--weights", "-w", envvar="COLONLIGHT_WEIGHTS",
    help="Checkpoint: ours (.safetensors with its .json card) or the authors' .pth. Default: the shipped model.",
)
ModelSize = typer.Option(
    None, "--model-size", envvar="COLONLIGHT_MODEL_SIZE",
    help="Network input size in pixels, 'full' for full-resolution input (the release's way), or 'auto' (the "
         "default): the size the weights were trained at (their card; 48 for the shipped model), else 48.",
)
Content = typer.Option(
    "auto", "--content", envvar="COLONLIGHT_CONTENT",
    help="auto: find the field of view inside a black border and fixed on-screen text, let the method see only "
         "them and write border and text pixels unchanged (a frame without either is processed as with full); "
         "full: the whole frame.",
)
Debug = typer.Option(False, "--debug", envvar="COLONLIGHT_DEBUG", help="Show tracebacks of errors.")
Quiet = typer.Option(False, "--quiet", "-q", envvar="COLONLIGHT_QUIET", help="No live display: one line per clip, for logs.")


def method_options(
    method: str, weights: Path | None, model_size: str | None, device: str, gamma: float | None = None
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
    if method == "gamma" and gamma is not None:
        opts["gamma"] = gamma
    elif gamma is not None:
        raise typer.BadParameter(f"--gamma applies only to --method gamma")
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
