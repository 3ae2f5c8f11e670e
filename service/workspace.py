"""The data folder's layout: ``jobs/<id>/`` (upload and results), ``uploads/`` (bodies being received),
``sync/`` (work of ``POST /v1/enhance``), and the job table beside them; one place that knows the paths."""

from __future__ import annotations

import errno
import os
import secrets
import shutil
from pathlib import Path

#: The name of a job's uploaded content mask in its folder (beside ``input<suffix>``); never a name the client sends.
MASK_NAME = "content_mask"


class Workspace:
    """The folders under ``data_dir`` and the names in them."""

    def __init__(self, data_dir: Path | str) -> None:
        self.root = Path(data_dir).resolve()
        self.jobs_dir = self.root / "jobs"
        self.uploads_dir = self.root / "uploads"
        self.sync_dir = self.root / "sync"
        self.table = self.root / "jobs.sqlite3"

    def create(self) -> None:
        """Make the folders (kept if there); OSError if they cannot be made or written. ``colonlight serve`` calls
        it before the server starts, so that a data folder no process could use is one line, not uvicorn's
        "Application startup failed" traceback."""
        for d in (self.jobs_dir, self.uploads_dir, self.sync_dir):
            d.mkdir(parents=True, exist_ok=True)
            if not os.access(d, os.W_OK | os.X_OK):
                raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(d))

    def prepare(self) -> None:
        """Make the folders, and remove the partial uploads and sync work of a process that died."""
        self.create()
        for leftover in list(self.uploads_dir.iterdir()) + list(self.sync_dir.iterdir()):
            remove(leftover)

    def remove_orphans(self, known: set[str]) -> None:
        """Remove the job folders whose row is gone (deleted while the process died)."""
        for d in self.jobs_dir.iterdir():
            if d.name not in known:
                remove(d)

    def job_dir(self, job_id: str) -> Path:
        return self.jobs_dir / job_id

    def new_upload_path(self) -> Path:
        return self.uploads_dir / f"{secrets.token_hex(16)}.part"

    def scrub(self, message: str, source: Path, filename: str, mask: tuple[Path, str] | None = None) -> str:
        """An engine message with the server's paths replaced by the client's file names (``mask``: the uploaded
        content mask's path and name)."""
        message = message.replace(str(source), filename)
        if mask is not None:
            message = message.replace(str(mask[0]), mask[1])
        return message.replace(str(self.root), "<data>")


def remove(path: Path) -> None:
    """Remove a file or a folder tree, whatever is there (nothing if it is gone)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
