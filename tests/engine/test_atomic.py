"""Atomic writes under an interrupt that lands just as the temporary's file is made: ``tempfile.mkstemp`` made
them, and an interrupt inside it, after the file existed, left a temporary that no caller knew the name of."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from colonlight.atomic import TMP_MARK, atomic_path, new_temporary, write_bytes_atomic, write_temporary

from ..faults import interrupt_after_creating


def _with_atomic_path(dest: Path) -> None:
    with atomic_path(dest) as tmp:
        tmp.write_bytes(b"new")


WRITES: dict[str, Callable[[Path], object]] = {
    "atomic_path": _with_atomic_path,
    "write_bytes_atomic": lambda dest: write_bytes_atomic(dest, b"new"),
    "write_temporary": lambda dest: write_temporary(dest, b"new"),
    "new_temporary": new_temporary,
}


@pytest.mark.parametrize("write", WRITES.values(), ids=WRITES.keys())
def test_an_interrupt_once_the_temporary_exists_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, write: Callable[[Path], object]
) -> None:
    dest = tmp_path / "out.json"
    dest.write_bytes(b"old")
    made = interrupt_after_creating(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        write(dest)
    assert len(made) == 1 and TMP_MARK in made[0]  # the interrupt came once the temporary's file existed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]
    assert dest.read_bytes() == b"old"


def test_temporaries_have_the_usual_permissions_and_a_temporarys_name(tmp_path: Path) -> None:
    import os

    umask = os.umask(0o022)
    try:
        tmp = new_temporary(tmp_path / "frame.png")
        other = new_temporary(tmp_path / "frame.png", suffix=".tmp.png")
    finally:
        os.umask(umask)
    assert tmp != other and tmp.name.startswith(".frame.png.") and tmp.name.endswith(TMP_MARK + ".png")
    assert other.name.endswith(TMP_MARK + ".tmp.png")
    assert tmp.stat().st_mode & 0o777 == 0o644 and tmp.read_bytes() == b""


@pytest.mark.parametrize("write", [_with_atomic_path, lambda dest: write_bytes_atomic(dest, b"new")])
def test_an_interrupt_on_the_way_to_the_rename_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, write: Callable[[Path], object]
) -> None:
    """The temporary is written and the interrupt lands as the rename is entered (``publish`` called, nothing
    renamed yet): the temporary's name is still held, so it goes, and the old file stays."""
    import colonlight.atomic

    def interrupted(tmp: Path, dest: Path) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(colonlight.atomic, "publish", interrupted)
    dest = tmp_path / "out.json"
    dest.write_bytes(b"old")
    with pytest.raises(KeyboardInterrupt):
        write(dest)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]
    assert dest.read_bytes() == b"old"
