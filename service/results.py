"""A finished job's results: the files the routes serve, ``frames.zip`` built once, and ``gammas.json``
labelled with the upload's name instead of the server's path."""

from __future__ import annotations

import threading
import zipfile
from pathlib import Path

from colonlight import GAMMAS_FILE, VIDEO_FILE, ClipJob, ClipOutcome, atomic_path, read_json, write_json_atomic

from .errors import is_disk_full
from .runners import DISK_FULL, NO_SPACE
from .store import JobRecord
from .workspace import Workspace


class Results:
    """The result files of the jobs in ``workspace``."""

    def __init__(self, workspace: Workspace) -> None:
        self.workspace = workspace
        self._zip_lock = threading.Lock()

    def path(self, rec: JobRecord, what: str) -> Path:
        out = self.workspace.job_dir(rec.id) / "out"
        return out / {"video": VIDEO_FILE, "gammas": GAMMAS_FILE}[what]

    def frames_zip(self, rec: JobRecord) -> Path:
        """``frames.zip`` of a finished job, built once (stored, not compressed: the frames are png/jpg)."""
        target = self.workspace.job_dir(rec.id) / "frames.zip"
        with self._zip_lock:
            if not target.is_file():
                frames_dir = self.workspace.job_dir(rec.id) / "out" / "frames"
                with atomic_path(target) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
                    for p in sorted(frames_dir.iterdir()):
                        if p.is_file() and not p.name.startswith("."):
                            zf.write(p, arcname=f"frames/{p.name}")
        return target


def label_source(outcome: ClipOutcome, job: ClipJob, label: str) -> ClipOutcome:
    """The finished clip's gammas.json with ``source`` naming the upload's label, not its server path."""
    gammas = job.out_dir / GAMMAS_FILE
    try:
        record = read_json(gammas)
        record["source"] = label
        write_json_atomic(gammas, record)
    except (OSError, ValueError) as exc:
        gammas.unlink(missing_ok=True)
        full = is_disk_full(exc)
        return ClipOutcome(
            outcome.name,
            outcome.source,
            "failed",
            seconds=outcome.seconds,
            error=NO_SPACE if full else f"its results could not be completed: {exc}",
            detail=DISK_FULL if full else None,
        )
    return outcome
