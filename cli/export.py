"""``colonlight export``: the network's step as ONNX (state as explicit inputs and outputs) plus a JSON sidecar."""

from __future__ import annotations

from pathlib import Path

import typer

from colonlight.errors import OptionError
from colonlight.limits import DEFAULT_MODEL_SIZE, MAX_MODEL_SIZE, MIN_MODEL_SIZE
from colonlight.methods.options import option

from . import options
from .display import console, printable
from .failures import FAILED, ends_command
from .interrupts import interruptible


def export(
    output: Path = typer.Option(..., "--output", "-o", help="The .onnx file to write; its sidecar is OUTPUT.json."),
    weights: Path | None = typer.Option(
        None,
        "--weights",
        "-w",
        envvar="COLONLIGHT_WEIGHTS",
        help="The rnn checkpoint: ours (.safetensors with its .json card) or the authors' .pth. Default: the "
        "shipped model.",
    ),
    model_size: str | None = typer.Option(
        None,
        "--model-size",
        envvar="COLONLIGHT_MODEL_SIZE",
        help=f"Network input size in pixels the graph is fixed at ({MIN_MODEL_SIZE}..{MAX_MODEL_SIZE}), or 'auto' "
        "(the default): the size the weights' card gives (32 for the shipped model), else "
        f"{DEFAULT_MODEL_SIZE}. 'full' cannot be exported.",
    ),
    debug: bool = options.Debug,
) -> None:
    """Write the network's step for ONNX Runtime hosts (frame and state in, output and state out), and its sidecar."""
    with ends_command(FAILED, debug):
        from colonlight import OutputError, export_onnx, load_weights, onnx_sidecar_path, parse_model_size

        try:
            checked = option("model_size").parse(model_size or "auto")  # the range enhance and the service take
        except OptionError as exc:
            raise typer.BadParameter(str(exc), param_hint="--model-size") from None
        loaded = load_weights(weights)
        size = parse_model_size(str(checked), trained_at=loaded.input_size)  # a size option parses to text
        if size is None:
            raise typer.BadParameter(
                "the graph has a fixed input size: give a number or 'auto'", param_hint="--model-size"
            )
        try:
            record = export_onnx(loaded, output, size)
        except OSError as exc:  # a disk full or a read-only folder: the output named, one line
            raise OutputError(f"{output}: cannot write ({exc.strerror or exc})") from exc
    check = record["check"]["onnxruntime_vs_torch_max_abs_diff"]
    outputs = ", ".join(o["name"] for o in record["outputs"])
    console.print(
        f"wrote {printable(str(output))} (opset {record['onnx']['opset']}, input {size}x{size}, outputs {outputs})",
        soft_wrap=True,
    )
    console.print(f"wrote {printable(str(onnx_sidecar_path(output)))}", soft_wrap=True)  # a name with [/] is no markup
    if check is not None:
        console.print(f"checked against torch: max |difference| {check:.2g}")


def register(app: typer.Typer) -> None:
    app.command("export")(interruptible(export))  # SIGTERM as Ctrl-C: temporaries removed, exit 143
