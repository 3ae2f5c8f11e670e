"""``colonlight info``: versions, the default model and its card, the compute device, the methods."""

from __future__ import annotations

import json

import typer

from colonlight import ColonlightError

from .display import out, printable


def info(as_json: bool = typer.Option(False, "--json", help="Machine-readable output.")) -> None:
    """Show versions, the default model (name, sha256, card), the device and the available methods."""
    import torch

    from colonlight import DEFAULT_WEIGHTS, available_methods, library_versions, load_weights

    versions, methods = library_versions(), available_methods()
    record: dict[str, object] = {"versions": versions, "methods": methods}
    try:
        w = load_weights(None)
        record["default_model"] = {"name": w.name, "path": str(w.path), "sha256": w.sha256, "card": w.card}
    except ColonlightError as exc:
        record["default_model"] = {"error": str(exc), "path": str(DEFAULT_WEIGHTS)}
    record["device"] = {
        "auto": "cuda:0" if torch.cuda.is_available() else "cpu",
        "cuda_devices": torch.cuda.device_count(),
        "torch_threads": torch.get_num_threads(),
    }
    if as_json:
        out.print_json(json.dumps(record))
        return
    for key, val in versions.items():
        out.print(f"{key:>24}: {val}")
    out.print(f"{'methods':>24}: {', '.join(methods)}")
    dm = record["default_model"]
    assert isinstance(dm, dict)
    if "error" in dm:
        out.print(f"{'default model':>24}: [red]{printable(str(dm['error']))}[/]", soft_wrap=True)
    else:
        card = dm["card"]
        out.print(f"{'default model':>24}: {dm['name']}  sha256 {dm['sha256'][:16]}...")
        out.print(f"{'':>24}  {printable(str(dm['path']))}", soft_wrap=True)
        if card:
            tr = card.get("training", {})
            shipped = tr.get("shipped_epoch")  # a run stopped or chosen before its last epoch
            epochs = f"epoch {shipped} of {tr.get('epochs')}" if shipped else f"{tr.get('epochs')} epochs"
            stages = len(tr.get("lineage", [])) or 1
            out.print(
                f"{'':>24}  input {card.get('input_size')} px; {'last run ' if stages > 1 else ''}trained "
                f"{epochs} on {tr.get('train_sequences')} sequences ({tr.get('data', 'see card')})"
                + (f"; {stages} runs in the card's lineage" if stages > 1 else "")
            )
    dev = record["device"]
    out.print(f"{'device (auto)':>24}: {dev['auto']}  ({dev['torch_threads']} CPU threads, {dev['cuda_devices']} CUDA)")  # type: ignore[index]


def register(app: typer.Typer) -> None:
    app.command("info")(info)
