"""The exact command that installs one of colonlight's optional extras (``eval``, ``cluster``, ``export``, ``docs``).

One place for that hint, so every "needs the X extra" message names a command that works where colonlight runs:
from a checkout installed with ``pip install -e .`` (``make demo``) it is ``pip install -e '.[eval]'`` (the
checkout's path when the current folder is elsewhere); from an installed wheel it is
``pip install 'colonlight[eval]'``. The pip is this interpreter's (a virtual environment's ``bin/pip`` when the
``pip`` on ``PATH`` is another one). The text holds ``[eval]`` literally: a shell that prints with markup escapes it.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

#: The extras pyproject.toml declares, with what each one is for.
EXTRAS = {
    "eval": "colonlight evaluate",
    "cluster": "colonlight enhance --cluster",
    "export": "colonlight export and --runtime onnxruntime",
    "docs": "scripts/make_figures.py",
}


def source_checkout() -> Path | None:
    """The repository colonlight runs from (an editable install: its ``pyproject.toml`` sits beside the package),
    or None for an installed wheel."""
    root = Path(__file__).resolve().parent.parent
    return root if (root / "pyproject.toml").is_file() and (root / "colonlight" / "__init__.py").is_file() else None


def _pip() -> str:
    """``pip`` when the one on PATH installs into this interpreter, else this environment's own pip."""
    bin_dir = Path(sys.executable).parent
    on_path = shutil.which("pip")
    if on_path is not None and Path(on_path).parent.resolve() == bin_dir.resolve():
        return "pip"
    own = bin_dir / "pip"
    if own.is_file():
        rel = os.path.relpath(own)
        return rel if not rel.startswith("..") else str(own)
    return f"{sys.executable} -m pip"


def install_command(extra: str) -> str:
    """The shell command that installs ``extra`` for this colonlight (``pip install -e '.[eval]'`` and the like)."""
    if extra not in EXTRAS:
        raise ValueError(f"unknown extra {extra!r}; colonlight has {', '.join(EXTRAS)}")
    root = source_checkout()
    if root is None:
        return f"{_pip()} install 'colonlight[{extra}]'"
    here = Path.cwd().resolve() if os.path.isdir(os.curdir) else None
    where = "." if here == root else str(root)
    return f"{_pip()} install -e '{where}[{extra}]'"


__all__ = ["EXTRAS", "install_command", "source_checkout"]
