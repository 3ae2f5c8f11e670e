"""Hostile-input sweep 10: paths whose parents or links cannot be used, named for what they are.

Defects found: ``export -o afile/x.onnx`` built and checked the whole graph, then said only "File exists"
(tests/cli/test_failures.py has that case; a link loop in the path is here), and ``content CLIP -o afile/m.pgm``
read the whole clip first; a clip
that is a symbolic link loop was "no such file or folder" to ``train`` and ``evaluate``, which sent the user looking
for a file that is there.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from colonlight import DEFAULT_WEIGHTS, InputError
from colonlight.atomic import files_written_together
from colonlight.sources import clip_kind

from ..commands import invoke_cli as invoke


def test_an_export_under_a_link_loop_says_so(tmp_path: Path) -> None:
    loop = tmp_path / "loop"
    os.symlink(loop, loop)
    code, output = invoke("export", "-w", str(DEFAULT_WEIGHTS), "-o", str(loop / "x.onnx"))
    assert code == 1 and f"{loop} is a dangling symbolic link (or a link loop)" in output, output


@pytest.mark.parametrize("kind", ["loop", "dangling"])
def test_a_clip_that_is_a_broken_link_is_named_as_one(tmp_path: Path, kind: str) -> None:
    link = tmp_path / "clip.mp4"
    os.symlink(link if kind == "loop" else tmp_path / "gone.mp4", link)
    with pytest.raises(InputError) as caught:
        clip_kind(link)
    cause = "symbolic link loop" if kind == "loop" else "not found (a dangling link, or moved or deleted?)"
    assert str(caught.value) == f"{link}: {cause}"


def test_a_clip_that_is_missing_is_no_such_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r": no such file or folder$"):
        clip_kind(tmp_path / "never.mp4")


def test_evaluating_a_link_loop_names_the_loop(tmp_path: Path) -> None:
    loop = tmp_path / "loop.mp4"
    os.symlink(loop, loop)
    code, output = invoke("evaluate", str(loop), "-o", str(tmp_path / "ev"), "--methods", "none", "--no-colmap")
    assert f"{loop}: symbolic link loop" in output, output
    assert "no such file" not in output


def test_a_content_mask_under_a_file_is_refused_before_the_clip_is_read(tmp_path: Path) -> None:
    blocker = tmp_path / "afile"
    blocker.write_bytes(b"x")
    clip = tmp_path / "never read.mp4"  # not there: the output is judged first
    code, output = invoke("content", str(clip), "-o", str(blocker / "m.pgm"))
    assert code == 2 and f"{blocker} is a file, not a folder" in output.replace("\n", " ").replace("│", ""), output
    assert blocker.read_bytes() == b"x"


def test_files_written_together_hold_their_folder_until_done(tmp_path: Path) -> None:
    """``export`` writes its graph and sidecar under this hold: a second writer (here a thread; another process
    alike, flock being per open file) waits, so two exports to one name leave one export's pair, never a graph
    beside another model's sidecar, and neither removes the other's temporaries as stale mid-write."""
    entered = threading.Event()

    def second_writer() -> None:
        with files_written_together(tmp_path):
            entered.set()

    with files_written_together(tmp_path):
        other = threading.Thread(target=second_writer)
        other.start()
        assert not entered.wait(0.3), "a second writer got in while the first held the folder"
    assert entered.wait(10)
    other.join()
    assert list(tmp_path.iterdir()) == []  # no lock file left behind
