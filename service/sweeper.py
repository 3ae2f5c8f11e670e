"""Expiry: jobs finished more than the TTL ago are deleted, and stale sync work folders removed, every
``sweep_interval_seconds``."""

from __future__ import annotations

import asyncio
import logging
import time

from .admission import JobBoard
from .lifecycle import JobLifecycle
from .settings import Settings
from .sync_enhance import SYNC_LEFTOVER_S
from .workspace import Workspace, remove

log = logging.getLogger("colonlight.service")


class Sweeper:
    """Deletes what has expired, now (:meth:`sweep`) or in a task of the event loop (:meth:`start`)."""

    def __init__(self, settings: Settings, workspace: Workspace, board: JobBoard, lifecycle: JobLifecycle) -> None:
        self.settings = settings
        self.workspace = workspace
        self.board = board
        self.lifecycle = lifecycle
        self._task: asyncio.Task[None] | None = None

    def start(self) -> None:
        self._task = asyncio.create_task(self._forever())

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()

    async def _forever(self) -> None:
        while True:
            await asyncio.sleep(self.settings.sweep_interval_seconds)
            try:
                await asyncio.to_thread(self.sweep)
            except Exception:  # a failed sweep is retried at the next interval
                log.exception("sweep failed")

    def sweep(self) -> int:
        """Delete jobs finished more than the TTL ago (and stale sync work folders); return how many jobs.

        The TTL in force is applied, so a server restarted with a shorter TTL also sweeps older results sooner."""
        store = self.lifecycle.store
        assert store is not None
        expired = store.finished_before(time.time() - self.settings.result_ttl_seconds)
        for job_id in expired:
            self.lifecycle.delete(job_id)
        cutoff = time.time() - SYNC_LEFTOVER_S
        busy = self.board.running_keys()
        for d in self.workspace.sync_dir.iterdir():
            if d.name not in busy and d.stat().st_mtime < cutoff:
                remove(d)
        if expired:
            log.info("swept %d expired job(s)", len(expired))
        return len(expired)
