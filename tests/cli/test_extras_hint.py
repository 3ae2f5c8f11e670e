"""The hint for a missing optional extra names a command that works here, with its ``[extra]`` printed."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from click.testing import Result
from colonlight_cli.main import app
from typer.testing import CliRunner

REPO = Path(__file__).resolve().parents[2]


def _colonlight_without(modules: str, *args: str, cwd: Path, monkeypatch: pytest.MonkeyPatch) -> Result:
    """``colonlight ARGS`` run from ``cwd`` with the named modules absent (``sys.modules[name] = None``: import
    fails and ``importlib.util.find_spec`` answers None, exactly as when the distribution is not installed), and
    a PATH without this environment's pip."""
    for name in modules.split(","):
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.chdir(cwd)
    return CliRunner().invoke(app, list(args), env={"PATH": "/usr/bin:/bin"})


def test_missing_eval_extra_hint_prints_the_extra_and_works_from_the_checkout(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    clip = tmp_path / "clip.mp4"
    clip.write_bytes(b"")
    result = _colonlight_without("pycolmap,evo", "evaluate", str(clip), cwd=REPO, monkeypatch=monkeypatch)
    assert result.exit_code == 2, result.output
    line = " ".join(result.output.split())
    assert "needs pycolmap, evo:" in line
    # this environment's own pip (PATH has none), the checkout installed editable, "[eval]" not eaten as markup
    pip = os.path.relpath(Path(sys.executable).parent / "pip", REPO)
    pip = pip if not pip.startswith("..") else str(Path(sys.executable).parent / "pip")
    assert f"{pip} install -e '.[eval]'" in line, line
    elsewhere = _colonlight_without(
        "skimage", "evaluate", str(clip), "--no-colmap", cwd=tmp_path, monkeypatch=monkeypatch
    )
    assert f"install -e '{REPO}[eval]'" in " ".join(elsewhere.output.split()), elsewhere.output


def test_missing_export_extra_hint_keeps_its_brackets(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    result = _colonlight_without(
        "onnx,onnxscript", "export", "-o", str(tmp_path / "m.onnx"), cwd=REPO, monkeypatch=monkeypatch
    )
    assert result.exit_code == 1
    assert "install -e '.[export]'" in " ".join(result.output.split()), result.output


def test_install_command_for_a_wheel_and_unknown_extras(monkeypatch: pytest.MonkeyPatch) -> None:
    from colonlight import extras

    monkeypatch.setattr(extras, "source_checkout", lambda: None)  # as from site-packages
    assert extras.install_command("cluster").endswith("install 'colonlight[cluster]'")
    with pytest.raises(ValueError, match="unknown extra"):
        extras.install_command("gpu")
