"""The job table: one SQLite file under the data directory, so that jobs outlive the process.

A row per job; the job's files live in ``DATA_DIR/jobs/<id>/`` (``input<suffix>`` and ``out/``). Rows are small
and every statement is short; one connection is shared behind a lock (SQLite serialises writers anyway), in WAL
mode so that readers never wait for the writer.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

STATUSES = ("queued", "running", "succeeded", "failed")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id           TEXT PRIMARY KEY,
    status       TEXT NOT NULL,
    filename     TEXT NOT NULL,
    input_name   TEXT NOT NULL,
    input_bytes  INTEGER NOT NULL,
    options      TEXT NOT NULL,
    created_at   REAL NOT NULL,
    started_at   REAL,
    finished_at  REAL,
    frames_done  INTEGER NOT NULL DEFAULT 0,
    frames_total INTEGER,
    seconds      REAL,
    attempts     INTEGER NOT NULL DEFAULT 0,
    error        TEXT,
    note         TEXT
);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs(status);
CREATE INDEX IF NOT EXISTS jobs_finished ON jobs(finished_at);
"""


@dataclass
class JobRecord:
    id: str
    status: str
    filename: str
    input_name: str
    input_bytes: int
    options: dict[str, Any]
    created_at: float
    started_at: float | None = None
    finished_at: float | None = None
    frames_done: int = 0
    frames_total: int | None = None
    seconds: float | None = None
    attempts: int = 0
    error: str | None = None
    note: str | None = None

    @staticmethod
    def from_row(row: sqlite3.Row) -> JobRecord:
        d = {k: row[k] for k in row.keys() if k in _FIELDS}  # noqa: SIM118 - a Row iterates over values  # columns of other versions are ignored
        d["options"] = json.loads(d["options"])
        return JobRecord(**d)


_FIELDS = frozenset(JobRecord.__dataclass_fields__)


class JobStore:
    """CRUD on the ``jobs`` table; every method is thread-safe and quick."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None, timeout=30)
        self._db.row_factory = sqlite3.Row
        with self._lock:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def insert(self, rec: JobRecord) -> None:
        with self._lock:
            self._db.execute(
                "INSERT INTO jobs (id, status, filename, input_name, input_bytes, options, created_at, frames_total) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    rec.id,
                    rec.status,
                    rec.filename,
                    rec.input_name,
                    rec.input_bytes,
                    json.dumps(rec.options),
                    rec.created_at,
                    rec.frames_total,
                ),
            )

    def get(self, job_id: str) -> JobRecord | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return JobRecord.from_row(row) if row else None

    def update(self, job_id: str, **values: Any) -> bool:
        """Set columns of one job; False if the job is gone (deleted meanwhile)."""
        if not values:
            return True
        cols = ", ".join(f"{k} = ?" for k in values)
        with self._lock:
            cur = self._db.execute(f"UPDATE jobs SET {cols} WHERE id = ?", (*values.values(), job_id))
        return cur.rowcount > 0

    def mark_running(self, job_id: str) -> JobRecord | None:
        """queued -> running (one more attempt); None if the job is no longer queued (deleted)."""
        with self._lock:
            cur = self._db.execute(
                "UPDATE jobs SET status = 'running', started_at = ?, attempts = attempts + 1, frames_done = 0 "
                "WHERE id = ? AND status = 'queued'",
                (time.time(), job_id),
            )
            if cur.rowcount == 0:
                return None
            row = self._db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return JobRecord.from_row(row)

    def requeue(self, job_id: str, note: str) -> bool:
        """running -> queued after a clean shutdown; the interrupted start does not count as an attempt."""
        with self._lock:
            cur = self._db.execute(
                "UPDATE jobs SET status = 'queued', frames_done = 0, note = ?, attempts = MAX(attempts - 1, 0) "
                "WHERE id = ?",
                (note, job_id),
            )
        return cur.rowcount > 0

    def delete(self, job_id: str) -> bool:
        with self._lock:
            cur = self._db.execute("DELETE FROM jobs WHERE id = ?", (job_id,))
        return cur.rowcount > 0

    def with_status(self, *statuses: str) -> list[JobRecord]:
        marks = ", ".join("?" for _ in statuses)
        with self._lock:
            rows = self._db.execute(
                f"SELECT * FROM jobs WHERE status IN ({marks}) ORDER BY created_at", statuses
            ).fetchall()
        return [JobRecord.from_row(r) for r in rows]

    def finished_before(self, cutoff: float) -> list[str]:
        """Ids of jobs that finished (succeeded or failed) at or before ``cutoff``."""
        with self._lock:
            rows = self._db.execute(
                "SELECT id FROM jobs WHERE finished_at IS NOT NULL AND finished_at <= ? "
                "AND status IN ('succeeded', 'failed')",
                (cutoff,),
            ).fetchall()
        return [r["id"] for r in rows]

    def ids(self) -> set[str]:
        with self._lock:
            return {r["id"] for r in self._db.execute("SELECT id FROM jobs").fetchall()}

    def counts(self) -> dict[str, int]:
        with self._lock:
            rows = self._db.execute("SELECT status, COUNT(*) AS n FROM jobs GROUP BY status").fetchall()
        counts = {s: 0 for s in STATUSES}
        counts.update({r["status"]: r["n"] for r in rows})
        return counts
