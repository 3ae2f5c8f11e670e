"""Loading and saving the gamma network's weights, in two formats, without ever unpickling arbitrary objects.

* Ours: ``NAME.safetensors`` (tensors only) plus ``NAME.json``, a model card (name, version, input size, how it was
  trained, and the sha256 of the safetensors file, checked on load).
* The authors' release: a plain PyTorch state dict (``.pth``) with keys ``in_cnv.*``, ``bn.*``, ``RNNcell.conv.*``,
  ``rnn_cnv.*``, ``out_linear.*``; read with ``torch.load(weights_only=True)``, which refuses anything but tensors
  and plain containers.
"""

from __future__ import annotations

import hashlib
import pickle
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from .atomic import NOT_REGULAR_FILE, atomic_path, read_json, write_json_atomic
from .errors import CheckpointError
from .limits import MAX_MODEL_SIZE, MIN_MODEL_SIZE
from .model import HEAD_OUTPUTS, INPUT_CHANNELS, GammaNet

WEIGHTS_DIR = Path(__file__).parent / "weights"
DEFAULT_WEIGHTS = WEIGHTS_DIR / "colonlight-rnn.safetensors"


@dataclass(frozen=True)
class LoadedWeights:
    """A network ready for inference and what identifies it in every output it makes."""

    net: GammaNet
    name: str
    sha256: str
    path: Path
    card: dict[str, Any] = field(default_factory=dict)

    @property
    def head(self) -> str:
        """``gamma`` (the paper's: one gamma per frame) or ``gain-gamma`` (see :mod:`colonlight.correction`)."""
        return self.net.head

    @property
    def seed_frames(self) -> int | None:
        """How many leading frames the weights were trained to pass through unchanged, when the card says."""
        seeds = self.card.get("seed_frames")
        return int(seeds) if seeds is not None else None

    @property
    def input_size(self) -> int | None:
        """The square input size the weights were trained at, when the card says."""
        size = self.card.get("input_size")
        return int(size) if size else None


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def card_path(weights: Path) -> Path:
    """The model card that sits beside a safetensors file."""
    return weights.with_suffix(".json")


def read_card(path: Path, digest: str) -> dict[str, Any]:
    """The model card beside the weights at ``path`` (``{}`` if there is none), checked against their sha256."""
    cp = card_path(path)
    if not cp.is_file():
        return {}
    try:
        card: dict[str, Any] = read_json(cp)
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{cp}: unreadable model card ({exc})") from exc
    if not isinstance(card, dict):
        raise CheckpointError(f"{cp}: unreadable model card (a JSON object expected, found {type(card).__name__})")
    for key, low, high in (("input_size", MIN_MODEL_SIZE, MAX_MODEL_SIZE), ("seed_frames", 0, 1 << 20)):
        value = card.get(key)
        whole = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
        if value is not None and (isinstance(value, bool) or not whole or not low <= value <= high):
            raise CheckpointError(f"{cp}: model card's {key} must be a whole number {low}..{high}, got {value!r}")
    if card.get("sha256") and card["sha256"] != digest:
        raise CheckpointError(f"{path}: sha256 {digest[:12]}... does not match its model card {cp.name}")
    return card


#: What torch.load says of a file it cannot read in words worth passing on.
_LOAD_ERRORS = (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile, ValueError, OSError)


def _weights_only_reason(text: str) -> str:
    """What torch's weights-only unpickler refused, in words for a user. Its own first line ("Weights only load
    failed. In PyTorch 2.6, we changed the default ... Re-running `torch.load` with `weights_only` set to `False`")
    says the same of random bytes and of a pickled model, suggests unpickling a file of unknown origin, and
    can carry terminal escapes; the cause is in its "WeightsUnpickler error:" part."""
    detail = text.partition("WeightsUnpickler error:")[2].strip()
    if detail.startswith("Unsupported global:"):  # "Unsupported global: GLOBAL pkg.Class was not an allowed ..."
        name = detail.removeprefix("Unsupported global:").split()[1:2] or ["an object"]
        return (
            f"it holds a pickled object ({name[0]}), not only tensors, and is not unpickled, which could run "
            "code: save the model's state_dict() instead"
        )
    return "its bytes are not a checkpoint torch can read"


def _state_dict_from_pth(path: Path) -> dict[str, torch.Tensor]:
    try:
        with warnings.catch_warnings():  # its "unusual pickle protocol" warning on garbage: the error below says it
            warnings.simplefilter("ignore", UserWarning)
            obj = torch.load(path, map_location="cpu", weights_only=True)
    # Any exception: on bytes that are not a checkpoint, the weights-only unpickler fails with whatever its
    # opcode table hits first (KeyError, IndexError, ... besides the documented ones), and a file we cannot
    # read is the one thing this can mean.
    except Exception as exc:  # noqa: BLE001
        said = isinstance(exc, _LOAD_ERRORS) and str(exc).strip()  # the others' text is an opcode's key or index
        reason = str(exc).strip().splitlines()[0] if said else "its bytes are not a checkpoint torch can read"
        if isinstance(exc, pickle.UnpicklingError):
            reason = _weights_only_reason(str(exc))
        raise CheckpointError(f"{path}: not a readable PyTorch state dict ({reason[:200]})") from exc
    if isinstance(obj, dict):
        for key in ("state_dict", "model", "model_state_dict"):
            if key in obj and isinstance(obj[key], dict):
                obj = obj[key]
                break
    if not isinstance(obj, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in obj.items()):
        raise CheckpointError(f"{path}: expected a state dict of named tensors, found {type(obj).__name__}")
    return {k.removeprefix("module."): v for k, v in obj.items()}


def _check_finite(state: dict[str, torch.Tensor], path: Path) -> None:
    """Refuse weights with NaN or infinite values: such a network gives no usable correction for any frame (the
    stream would leave every frame unchanged, flagged), so a damaged file is said to be one at load."""
    for key, tensor in state.items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise CheckpointError(f"{path}: non-finite values (NaN or infinity) in {key}")


def _head_of(state: dict[str, torch.Tensor], card: dict[str, Any], path: Path) -> str:
    """The head the weights were trained with: from the output layer's shape, checked against the card."""
    weight = state.get("out_linear.weight")
    outputs = int(weight.shape[0]) if isinstance(weight, torch.Tensor) and weight.ndim == 2 else 1
    heads = {n: h for h, n in HEAD_OUTPUTS.items()}
    if outputs not in heads:
        raise CheckpointError(f"{path}: output layer has {outputs} outputs; no head has that many")
    head = heads[outputs]
    if card.get("head", head) != head:
        raise CheckpointError(f"{path}: model card says head {card['head']!r}, the weights have {head!r}")
    return head


def _inputs_of(state: dict[str, torch.Tensor], card: dict[str, Any], path: Path) -> str:
    """The input the weights read (``model.INPUT_CHANNELS``): the card's, checked against the first convolution's
    shape; without a card, the one input with that many channels (3: ``rgb``, the paper's)."""
    weight = state.get("in_cnv.weight")
    channels = int(weight.shape[1]) if isinstance(weight, torch.Tensor) and weight.ndim == 4 else 3
    fits = [name for name, n in INPUT_CHANNELS.items() if n == channels]
    if not fits:
        raise CheckpointError(f"{path}: first convolution reads {channels} channels; no input has that many")
    said = card.get("inputs")
    if said is None:
        if len(fits) > 1:
            raise CheckpointError(
                f"{path}: first convolution reads {channels} channels, which could be {' or '.join(fits)}; "
                "its model card must say which (inputs)"
            )
        return fits[0]
    if said not in fits:
        raise CheckpointError(f"{path}: model card says inputs {said!r}, the weights read {channels} channels")
    return str(said)


def _net_from_state_dict(
    state: dict[str, torch.Tensor], path: Path, head: str = "gamma", inputs: str = "rgb"
) -> GammaNet:
    net = GammaNet(head=head, inputs=inputs)
    expected = set(net.state_dict())
    missing = sorted(expected - set(state))
    unexpected = sorted(set(state) - expected)
    if missing or unexpected:
        raise CheckpointError(
            f"{path}: not a colonlight/ColonLight gamma network "
            f"(missing {missing[:3]}{'...' if len(missing) > 3 else ''}, "
            f"unexpected {unexpected[:3]}{'...' if len(unexpected) > 3 else ''})"
        )
    try:
        net.load_state_dict(state)
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: tensor shapes do not match the network ({str(exc).splitlines()[0]})") from exc
    return net.eval()


def load_weights(path: Path | str | None = None) -> LoadedWeights:
    """Load our safetensors format (with its card) or the authors' ``.pth`` state dict; ``None`` = the default.

    Raises :class:`CheckpointError` with a one-line reason for a missing, truncated, corrupt or foreign file.
    """
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    try:
        if not path.is_file():
            hint = " (the default model is missing from this installation)" if path == DEFAULT_WEIGHTS else ""
            if path.is_dir():
                raise CheckpointError(f"{path}: a folder, not a checkpoint file{hint}")
            raise CheckpointError(f"{path}: {NOT_REGULAR_FILE if path.exists() else 'no such checkpoint file'}{hint}")
    except OSError as exc:  # a name past NAME_MAX (ENAMETOOLONG): is_file raises it, a traceback before
        raise CheckpointError(f"{path}: cannot read the checkpoint file ({exc.strerror or exc})") from None
    try:
        digest = sha256_file(path)
    except OSError as exc:  # permission denied, an I/O error: a traceback in enhance, "cannot write" in export
        raise CheckpointError(f"{path}: cannot read the checkpoint file ({exc.strerror or exc})") from None
    card: dict[str, Any] = {}
    if path.suffix == ".safetensors":
        try:
            state = load_file(str(path))
        except (SafetensorError, OSError, ValueError) as exc:
            raise CheckpointError(f"{path}: corrupt or truncated safetensors file ({exc})") from exc
        card = read_card(path, digest)
        name = str(card.get("name") or path.stem)
    else:
        state = _state_dict_from_pth(path)
        name = path.stem
    # BatchNorm's step counter is bookkeeping for training only; older saves may lack it.
    state.setdefault("bn.num_batches_tracked", torch.tensor(0, dtype=torch.long))
    _check_finite(state, path)
    net = _net_from_state_dict(state, path, _head_of(state, card, path), _inputs_of(state, card, path))
    return LoadedWeights(net=net, name=name, sha256=digest, path=path, card=card)


def save_tensors(state: dict[str, torch.Tensor], path: Path, file_format: str) -> None:
    """Write ``state`` as safetensors at ``path`` (atomically) with one metadata entry, ``format``.

    One entry, not several: safetensors writes its metadata map in an order that changes from one save to the
    next (a hash map), so two entries made the same weights differ in bytes, and in sha256, between saves.
    What else identifies the weights (name, variant) is in the model card beside them."""
    with atomic_path(path) as tmp:
        save_file(state, str(tmp), metadata={"format": file_format})


def save_weights(net: GammaNet, path: Path, card: dict[str, Any]) -> dict[str, Any]:
    """Save ``net`` as safetensors plus its model card (atomically); return the card with its sha256 filled in."""
    path = Path(path)
    state = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    save_tensors(state, path, "colonlight-gammanet")
    card = {**card, "sha256": sha256_file(path), "file": path.name}
    write_json_atomic(card_path(path), card)
    return card
