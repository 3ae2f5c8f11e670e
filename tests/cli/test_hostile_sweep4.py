"""A fourth hostile-input sweep of the CLI, through real ``colonlight`` processes on real files: JSON nested deeper
than Python's decoder goes (a model card, a batch's manifest.json, a clip's gammas.json), clips whose output
folder would take a name the output folder keeps for itself (``manifest.json.mp4``, a folder ``manifest.json/``),
and an export onto a FIFO. Each is a usage error or one line naming the file and the cause, never a traceback;
the rest of the batch goes on and nothing already there is lost."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest

from ..commands import run_colonlight
from ..media import make_clip, needs_ffmpeg

pytestmark = [needs_ffmpeg, pytest.mark.timeout(300)]

GAMMA = ("--method", "gamma", "-q", "-j", "1")
SHIPPED = Path(__file__).resolve().parents[2] / "colonlight" / "weights" / "colonlight-rnn"
#: deeper than Python's recursion limit: json.loads raises RecursionError, not ValueError
DEEP = "[" * 5000 + "]" * 5000


def clips_of(out: Path) -> dict[str, str]:
    return {e["clip"]: e["status"] for e in json.loads((out / "manifest.json").read_text())["clips"]}


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clip(tmp_path_factory.mktemp("clip") / "a.mp4", 8, size=(64, 48))


def test_a_model_card_nested_too_deep_is_one_line(clip: Path, tmp_path: Path) -> None:
    """json.loads raises RecursionError on it, which the card reader did not catch (it caught ValueError)."""
    weights = tmp_path / "w.safetensors"
    weights.write_bytes(SHIPPED.with_suffix(".safetensors").read_bytes())
    (tmp_path / "w.json").write_text(DEEP)
    out = tmp_path / "out"
    code, output = run_colonlight("enhance", str(clip), "-o", str(out), "-w", str(weights), "-q", "-j", "1")
    assert code == 2, output
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: {tmp_path / 'w.json'}: unreadable model card"), output


@pytest.mark.parametrize(
    ("where", "content"),
    [("manifest.json", DEEP), ("a/gammas.json", DEEP), ("a/gammas.json", "[1]")],
    ids=["manifest-deep", "gammas-deep", "gammas-list"],
)
def test_a_damaged_record_in_the_output_folder_is_redone_not_fatal(
    clip: Path, tmp_path: Path, where: str, content: str
) -> None:
    """A manifest.json nested too deep stopped the whole batch with a traceback; a clip's gammas.json nested too
    deep, or valid JSON that is not an object, failed the clip as an "internal error" on every rerun, where any
    other unreadable record is taken as an unfinished clip and redone."""
    out = tmp_path / "out"
    (out / where).parent.mkdir(parents=True, exist_ok=True)
    (out / where).write_text(content)
    code, output = run_colonlight("enhance", str(clip), "-o", str(out), *GAMMA)
    assert code == 0, output
    assert clips_of(out) == {"a": "done"}
    assert json.loads((out / "a" / "gammas.json").read_text())["frame_count"] > 0


def test_clips_named_like_the_manifest_do_not_take_its_place(tmp_path: Path) -> None:
    """``manifest.json.mp4`` was written to ``OUT/manifest.json/``: the batch's manifest could then never be
    written (exit 1 on this run and every rerun, "rerun to record them"). It now takes its suffix, as clips
    whose names collide do; a clip inside a folder named ``manifest.json`` fails alone, saying why; a clip
    named ``.colonlight.lock.mp4`` no longer fails on the output folder's lock file."""
    videos = tmp_path / "videos"
    make_clip(videos / "manifest.json.mp4", 8, size=(64, 48))
    make_clip(videos / "ok.mp4", 8, size=(64, 48), first_index=50)
    make_clip(videos / "manifest.json" / "p7.mp4", 8, size=(64, 48), first_index=100)
    lock_named = make_clip(tmp_path / ".colonlight.lock.mp4", 8, size=(64, 48), first_index=150)
    out = tmp_path / "out"
    for _ in range(2):  # a rerun finds everything recorded
        code, output = run_colonlight("enhance", str(videos), str(lock_named), "-o", str(out), *GAMMA)
        assert code == 1, output  # the clip in the folder named manifest.json
        assert (out / "manifest.json").is_file()
        assert clips_of(out) == {
            "manifest.json-mp4": "done",
            "ok": "done",
            "manifest.json/p7": "failed",
            ".colonlight.lock-mp4": "done",
        }
        failed = [line for line in output.splitlines() if line.startswith("failed")]
        assert len(failed) == 1 and str(videos / "manifest.json" / "p7.mp4") in failed[0], output
        assert "a name the output folder keeps for itself" in failed[0], output
    assert not (out / "manifest.json" / "p7").exists()
    assert (out / "manifest.json-mp4" / "gammas.json").is_file()


def test_export_onto_a_fifo_leaves_it_alone(tmp_path: Path) -> None:
    """The atomic rename replaced the FIFO (or, as root, ``-o /dev/null``: the device node itself) with a regular
    file holding the graph, and wrote ``/dev/null.json`` beside it."""
    fifo = tmp_path / "graph.onnx"
    os.mkfifo(fifo)
    code, output = run_colonlight("export", "-o", str(fifo))
    assert code == 1, output
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: {fifo}: not a regular file"), output
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["graph.onnx"]
