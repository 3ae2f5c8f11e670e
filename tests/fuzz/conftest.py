"""Fixtures of the fuzz suite: the seed clips (made once per session) and a folder for each case's files."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from ..media import ffmpeg_exe
from .corrupt import make_seeds


@pytest.fixture(scope="session")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    if ffmpeg_exe() is None:
        pytest.skip("imageio-ffmpeg's ffmpeg binary is not available")
    return make_seeds(tmp_path_factory.mktemp("fuzz-seeds"))


@pytest.fixture(scope="module")
def case_dir(tmp_path_factory: pytest.TempPathFactory) -> Callable[[], Iterator[Path]]:
    """``with case_dir() as d:`` a fresh folder per hypothesis case (function-scoped tmp_path is one per test),
    removed when the case passes and kept for a look when it fails."""
    root = tmp_path_factory.mktemp("fuzz-cases")

    @contextmanager
    def make() -> Iterator[Path]:
        d = Path(tempfile.mkdtemp(dir=root))
        yield d
        shutil.rmtree(d, ignore_errors=True)

    return make
