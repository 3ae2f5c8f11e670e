"""A finished job's results: the files the routes serve, ``frames.zip`` built once, and ``gammas.json``
labelled with the upload's name instead of the server's path."""

from __future__ import annotations

import threading
import zipfile
from pathlib import Path
from typing import Any

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


def mask_setting(name: str, sha256: str) -> dict[str, str]:
    """What a job records of an uploaded content mask: the engine's record of a mask (``content_setting``), its
    upload name in place of the path on the server."""
    return {"mask": name, "sha256": sha256}


def mask_label(options: dict[str, Any]) -> str | None:
    """The upload name of the content mask a job's recorded ``options`` name, or None (``auto``/``full``)."""
    content = options.get("content")
    return str(content["mask"]) if isinstance(content, dict) else None


def relabel(record: dict[str, Any], label: str, mask: str | None = None) -> dict[str, Any]:
    """A gammas.json record naming the upload (``label``) and its content mask (``mask``) instead of the server's
    paths; the mask's SHA-256 stays as the engine recorded it."""
    record["source"] = label
    content = record.get("settings", {}).get("content")
    if mask is not None and isinstance(content, dict):
        content["mask"] = mask
    return record


def label_source(outcome: ClipOutcome, job: ClipJob, label: str, mask: str | None = None) -> ClipOutcome:
    """The finished clip's gammas.json with ``source`` naming the upload's label, not its server path (and the
    settings naming the uploaded content mask ``mask`` by its upload name)."""
    gammas = job.out_dir / GAMMAS_FILE
    try:
        write_json_atomic(gammas, relabel(read_json(gammas), label, mask))
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
