"""Both checkpoint formats load; broken files give one clear CheckpointError; nothing arbitrary is unpickled."""

from __future__ import annotations

import json
import pickle
import stat
from pathlib import Path

import numpy as np
import pytest
import torch

from colonlight.checkpoint import card_path, load_weights, save_weights, sha256_file
from colonlight.errors import CheckpointError
from colonlight.model import GammaNet


def test_authors_checkpoint_loads(authors_checkpoint: Path, reference_dir: Path) -> None:
    w = load_weights(authors_checkpoint)
    expected = json.loads((reference_dir / "expected.json").read_text())["checkpoint_sha256"]
    assert w.sha256 == expected
    assert w.name == authors_checkpoint.stem
    assert not w.net.training


def test_roundtrip_ours(tmp_path: Path) -> None:
    torch.manual_seed(3)
    net = GammaNet().eval()
    card = save_weights(net, tmp_path / "m.safetensors", {"name": "m", "input_size": 64})
    assert card["sha256"] == sha256_file(tmp_path / "m.safetensors")
    w = load_weights(tmp_path / "m.safetensors")
    assert w.name == "m" and w.input_size == 64
    for k, v in net.state_dict().items():
        assert torch.equal(v, w.net.state_dict()[k])


def test_saved_weights_get_the_usual_permissions_like_every_other_output(tmp_path: Path) -> None:
    """safetensors replaces the file it writes, with a private mode; the weights must still get the mode the
    umask gives every output, as the card beside them does."""
    path = tmp_path / "w.safetensors"
    save_weights(GammaNet(), path, {"name": "w"})
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(card_path(path).stat().st_mode)


def test_the_same_weights_saved_again_are_the_same_bytes(tmp_path: Path) -> None:
    """Reproducible outputs start with the weights: saving a network twice gives one sha256 (safetensors writes
    a metadata map of several entries in a changing order, so only one is written)."""
    torch.manual_seed(5)
    net = GammaNet(head="gain-gamma")
    digests = {save_weights(net, tmp_path / f"w{i}.safetensors", {"name": "w"})["sha256"] for i in range(8)}
    assert len(digests) == 1


def test_authors_to_ours_conversion_keeps_outputs(authors_checkpoint: Path, tmp_path: Path) -> None:
    w = load_weights(authors_checkpoint)
    save_weights(w.net, tmp_path / "conv.safetensors", {"name": "converted"})
    w2 = load_weights(tmp_path / "conv.safetensors")
    x = torch.rand(1, 3, 32, 32)
    with torch.no_grad():
        assert torch.equal(w.net.step(x)[0], w2.net.step(x)[0])


def _saved(tmp_path: Path) -> Path:
    path = tmp_path / "m.safetensors"
    save_weights(GammaNet(), path, {"name": "m"})
    return path


def test_truncated_safetensors(tmp_path: Path) -> None:
    path = _saved(tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    card_path(path).unlink()
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        load_weights(path)


def test_card_hash_mismatch(tmp_path: Path) -> None:
    path = _saved(tmp_path)
    card = json.loads(card_path(path).read_text())
    card["sha256"] = "0" * 64
    card_path(path).write_text(json.dumps(card))
    with pytest.raises(CheckpointError, match="does not match its model card"):
        load_weights(path)


def test_truncated_pth(authors_checkpoint: Path, tmp_path: Path) -> None:
    bad = tmp_path / "cut.pth"
    bad.write_bytes(authors_checkpoint.read_bytes()[:5000])
    with pytest.raises(CheckpointError, match="cut.pth"):
        load_weights(bad)


def test_garbage_and_missing(tmp_path: Path) -> None:
    (tmp_path / "x.pth").write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match=r"x\.pth"):
        load_weights(tmp_path / "x.pth")
    with pytest.raises(CheckpointError, match="no such checkpoint"):
        load_weights(tmp_path / "missing.safetensors")


@pytest.mark.parametrize("seed", range(40))
def test_any_garbage_bytes_are_a_checkpoint_error(tmp_path: Path, seed: int) -> None:
    """Bytes that are not a checkpoint make the weights-only unpickler fail in many ways (KeyError, IndexError,
    ...): every one is a CheckpointError naming the file, never an exception a caller cannot expect."""
    rng = np.random.default_rng(seed)
    path = tmp_path / f"garbage{seed}.pth"
    path.write_bytes(b"junk\n" if seed == 0 else rng.integers(0, 256, int(rng.integers(1, 200)), np.uint8).tobytes())
    with pytest.raises(CheckpointError, match=f"garbage{seed}.pth"):
        load_weights(path)


def test_a_state_dict_with_unnamed_entries_is_refused(tmp_path: Path) -> None:
    torch.save({1: torch.zeros(1)}, tmp_path / "ints.pth")
    with pytest.raises(CheckpointError, match="named tensors"):
        load_weights(tmp_path / "ints.pth")


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
@pytest.mark.parametrize("fmt", ["pth", "safetensors"])
def test_non_finite_weights_are_refused(tmp_path: Path, value: float, fmt: str) -> None:
    """A network with a NaN or infinite weight corrects no frame; loading says so rather than every frame's
    record reading "clamped"."""
    net = GammaNet()
    with torch.no_grad():
        net.rnn_cnv.weight[0, 0, 0, 0] = value
    path = tmp_path / f"damaged.{fmt}"
    if fmt == "pth":
        torch.save(net.state_dict(), path)
    else:
        save_weights(net, path, {"name": "damaged"})
    with pytest.raises(CheckpointError, match=r"damaged\..*non-finite values .* in rnn_cnv\.weight"):
        load_weights(path)


class _Evil:
    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (print, ("pwned",))


def test_arbitrary_pickles_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "evil.pth"
    torch.save({"in_cnv.weight": _Evil()}, path)
    with pytest.raises(CheckpointError):
        load_weights(path)
    path2 = tmp_path / "evil2.pth"
    path2.write_bytes(pickle.dumps(_Evil()))
    with pytest.raises(CheckpointError):
        load_weights(path2)


def test_wrong_network(tmp_path: Path) -> None:
    path = tmp_path / "other.pth"
    torch.save({"fc.weight": torch.zeros(2, 2)}, path)
    with pytest.raises(CheckpointError, match="not a colonlight"):
        load_weights(path)
    sd = GammaNet().state_dict()
    sd["in_cnv.weight"] = torch.zeros(16, 3, 3, 3)
    torch.save(sd, tmp_path / "shape.pth")
    with pytest.raises(CheckpointError, match="shapes"):
        load_weights(tmp_path / "shape.pth")
