"""Startup stays light: ``import colonlight`` and the CLI load only what a command needs (issue 3, performance)."""

from __future__ import annotations

import subprocess
import sys

import pytest


def _modules_after(code: str) -> set[str]:
    out = subprocess.run(
        [sys.executable, "-c", f"{code}\nimport sys\nprint(' '.join(sys.modules))"],
        capture_output=True,
        text=True,
        check=True,
    )
    return set(out.stdout.split())


def test_import_colonlight_is_lazy() -> None:
    mods = _modules_after("import colonlight")
    assert not {"torch", "av", "cv2"} & mods
    mods = _modules_after("import colonlight; colonlight.gamma_lut(0.5)")
    assert "cv2" in mods and "torch" not in mods


def test_lazy_names_resolve_and_unknown_names_raise() -> None:
    import colonlight

    for name in colonlight.__all__:
        assert getattr(colonlight, name) is not None
    assert set(dir(colonlight)) >= set(colonlight.__all__)
    with pytest.raises(AttributeError):
        colonlight.no_such_name  # noqa: B018


def test_cli_import_leaves_out_training_evaluation_and_service() -> None:
    mods = _modules_after("import colonlight_cli.main")
    for heavy in ("torch", "kornia", "colonlight.train", "colonlight.evaluation", "fastapi", "colonlight_service"):
        assert heavy not in mods, heavy


def test_is_available_imports_only_the_method_asked_for() -> None:
    mods = _modules_after(
        "from colonlight.methods import is_available; assert is_available('none')\n"
        "assert not is_available('no-such-method')"
    )
    assert "colonlight.methods.identity" in mods
    assert not {"colonlight.methods.zerodce", "colonlight.methods.deflicker", "torch"} & mods


def test_reuse_frame_memory_is_safe_to_repeat() -> None:
    from colonlight.tuning import reuse_frame_memory

    first = reuse_frame_memory()
    assert reuse_frame_memory() == first
    if sys.platform.startswith("linux"):
        assert isinstance(first, bool)
