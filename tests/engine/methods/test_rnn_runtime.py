"""``--runtime onnxruntime``: the rnn method's step on ONNX Runtime gives torch's gammas, caches its graph, and
refuses what it cannot run with one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

pytest.importorskip("onnxruntime", reason="the export extra (onnxruntime) is not installed")
pytest.importorskip("onnxscript", reason="the export extra (onnxscript) is not installed")

from colonlight_cli.main import app  # noqa: E402

from colonlight.methods.rnn import RecurrentGammaMethod  # noqa: E402
from colonlight.methods.rnn_onnx import cache_dir  # noqa: E402

from ...media import make_vfr_clip, vfr_times  # noqa: E402

runner = CliRunner()


@pytest.fixture(scope="module")
def onnx_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("cache")


def test_enhance_on_onnxruntime_gives_torchs_gammas_and_caches_the_graph(
    tmp_path: Path, onnx_cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLONLIGHT_CACHE_DIR", str(onnx_cache))
    make_vfr_clip(tmp_path / "clip.mp4", vfr_times(40), size=(160, 120))
    records = {}
    for runtime in ("torch", "onnxruntime"):
        out = tmp_path / runtime
        result = runner.invoke(
            app, ["enhance", str(tmp_path / "clip.mp4"), "-o", str(out), "--fps", "0", "-q", "--runtime", runtime]
        )
        assert result.exit_code == 0, result.output
        records[runtime] = json.loads((out / "clip" / "gammas.json").read_text())
    assert records["onnxruntime"]["parameters"]["runtime"] == "onnxruntime"
    assert "runtime" not in records["torch"]["parameters"]  # torch's records are unchanged by the option
    # the head's raw outputs: "a" (gamma head) or "z" (gain-gamma head, the shipped one)
    a = {r: np.array([f["a"] if "a" in f else f["z"] for f in rec["frames"]], np.float64) for r, rec in records.items()}
    assert a["torch"].std() > 1e-3
    assert np.max(np.abs(a["onnxruntime"] - a["torch"])) <= 1e-5
    gammas = {r: np.array([f["gamma"] for f in rec["frames"]]) for r, rec in records.items()}
    assert np.max(np.abs(gammas["onnxruntime"] - gammas["torch"])) <= 1e-4
    cached = list(cache_dir().glob("*.onnx"))
    size = records["torch"]["parameters"]["model_size"]  # the card's (32 for the shipped model)
    assert len(cached) == 1 and cached[0].name.startswith(f"{records['torch']['model']['sha256'][:16]}-{size}px-")
    # A second build reads the cached graph (no export); a damaged cache is exported again and replaced.
    frame = np.full((120, 160, 3), 90, np.uint8)
    expected = RecurrentGammaMethod(device="cpu").stream().predict_a(frame)
    before = cached[0].stat().st_mtime_ns
    assert abs(RecurrentGammaMethod(device="cpu", runtime="onnxruntime").stream().predict_a(frame) - expected) <= 1e-5
    assert cached[0].stat().st_mtime_ns == before
    cached[0].write_bytes(b"not an onnx graph")
    assert abs(RecurrentGammaMethod(device="cpu", runtime="onnxruntime").stream().predict_a(frame) - expected) <= 1e-5
    assert cached[0].read_bytes()[:4] != b"not "


def test_what_onnxruntime_cannot_run_is_refused_in_one_line(
    tmp_path: Path, onnx_cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLONLIGHT_CACHE_DIR", str(onnx_cache))
    make_vfr_clip(tmp_path / "clip.mp4", vfr_times(4))
    cases = {
        ("--model-size", "full"): "needs a fixed network input size",
        ("--method", "none"): "applies only to method rnn",
        ("--device", "cuda"): "cuda",
    }
    for extra, message in cases.items():
        result = runner.invoke(
            app, ["enhance", str(tmp_path / "clip.mp4"), "-o", str(tmp_path / "o"), "--runtime", "onnxruntime", *extra]
        )
        assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output, extra
    bad = runner.invoke(app, ["enhance", str(tmp_path / "clip.mp4"), "-o", str(tmp_path / "o"), "--runtime", "tvm"])
    assert bad.exit_code == 2 and "one of torch, onnxruntime" in bad.output
