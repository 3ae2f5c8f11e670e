"""The hint for a missing optional extra names a command that works here, with its ``[extra]`` printed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import Result
from colonlight_cli.main import app
from typer.testing import CliRunner

from tests.media import make_clip

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
    assert result.exit_code == 2  # a missing extra is a usage error, as for every command and option
    assert "install -e '.[export]'" in " ".join(result.output.split()), result.output


def test_install_command_for_a_wheel_and_unknown_extras(monkeypatch: pytest.MonkeyPatch) -> None:
    from colonlight import extras

    monkeypatch.setattr(extras, "source_checkout", lambda: None)  # as from site-packages
    assert extras.install_command("cluster").endswith("install 'colonlight[cluster]'")
    with pytest.raises(ValueError, match="unknown extra"):
        extras.install_command("gpu")


def _fresh_process_without(modules: list[str], *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``colonlight ARGS`` in a new interpreter where the named modules cannot be imported, as for a user who
    never installed the extra (a fresh process: nothing of the extra is imported already, as it may be here)."""
    code = (
        "import sys\n"
        f"for name in {modules!r}: sys.modules[name] = None\n"
        "from colonlight_cli.main import run\n"
        f"sys.argv = ['colonlight', *{list(args)!r}]\n"
        "run()\n"
    )
    env = {**os.environ, "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_evaluate_without_any_of_the_eval_extra_says_what_to_install(tmp_path: Path) -> None:
    from colonlight.evaluation.requirements import ALWAYS_NEEDED, COLMAP_NEEDED

    clip = make_clip(tmp_path / "clip.mp4", n_frames=6)
    done = _fresh_process_without([*ALWAYS_NEEDED, *COLMAP_NEEDED], "evaluate", str(clip), cwd=REPO)
    out = " ".join((done.stdout + done.stderr).split())
    assert done.returncode == 2 and "Traceback" not in out, out
    assert "needs scikit-image, matplotlib, scipy, pycolmap, evo:" in out and "install -e '.[eval]'" in out, out


def test_enhance_on_a_cluster_without_dask_says_what_to_install(tmp_path: Path) -> None:
    clip = make_clip(tmp_path / "clip.mp4", n_frames=6)
    args = ("enhance", str(clip), "-o", str(tmp_path / "out"), "--cluster", "tcp://127.0.0.1:1", "-q")
    done = _fresh_process_without(["distributed"], *args, cwd=REPO)
    out = " ".join((done.stdout + done.stderr).split())
    assert done.returncode == 2 and "Traceback" not in out, out  # exit 1 before: evaluate's was 2
    assert "needs Dask distributed" in out and "install -e '.[cluster]'" in out, out
