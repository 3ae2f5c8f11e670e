"""A finished job's ``gammas.json`` is relabelled with the upload's name; when that rewrite fails, the job fails
with the reason (the outcome keeps the clip's name and source), and no half-relabelled file is left."""

from __future__ import annotations

import json
from pathlib import Path

from colonlight_service.results import label_source

from colonlight import GAMMAS_FILE, ClipJob, ClipOutcome


def _job(tmp_path: Path, gammas: str) -> ClipJob:
    out = tmp_path / "out"
    out.mkdir()
    (out / GAMMAS_FILE).write_text(gammas, encoding="utf-8")
    return ClipJob(source=tmp_path / "input.mp4", name="clip", out_dir=out)


def test_a_finished_clip_is_labelled_with_the_upload_name(tmp_path: Path) -> None:
    job = _job(tmp_path, json.dumps({"source": str(tmp_path / "input.mp4"), "gammas": [1.0]}))
    done = ClipOutcome("clip", str(job.source), "done", frames=1, seconds=0.5)
    assert label_source(done, job, "my video.mp4") is done
    record = json.loads((job.out_dir / GAMMAS_FILE).read_text(encoding="utf-8"))
    assert record == {"source": "my video.mp4", "gammas": [1.0]}


def test_a_gammas_file_that_cannot_be_relabelled_fails_the_clip_by_name(tmp_path: Path) -> None:
    job = _job(tmp_path, '{"source": "cut sh')  # not JSON: the rewrite cannot read it
    done = ClipOutcome("clip", str(job.source), "done", frames=1, seconds=0.5)
    failed = label_source(done, job, "my video.mp4")
    assert (failed.name, failed.source, failed.status, failed.seconds) == ("clip", str(job.source), "failed", 0.5)
    assert failed.error is not None and failed.error.startswith("its results could not be completed: ")
    assert failed.detail is None  # not a full disk
    assert not (job.out_dir / GAMMAS_FILE).exists()
