"""The output folder of a batch: usable (a writable folder) and used by one batch at a time.

Two batches writing one folder would delete each other's temporaries (each clip clears stale ones first) and
overwrite each other's manifest, so a batch holds an exclusive ``flock`` on ``OUT/.colonlight.lock`` from start to
end. The lock file records who holds it (pid, host, start time, command) so that a second batch can say so; the
kernel drops the lock when its holder exits, however it exits (``kill -9`` included), so a stale file never blocks.
The file stays in place, emptied (removing a lock file races with a process about to lock it), and marks the
folder as a colonlight output, which discovery never searches as input.

Within one process the lock is re-entrant (the CLI takes it before discovery, :func:`colonlight.batch.run_batch`
takes it again); it does not serialise threads of one process.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import socket
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .atomic import parse_json
from .discovery import OUTPUT_MARKER
from .errors import ColonlightError, os_error_cause

#: The lock file of a ``colonlight train`` run folder (two runs into one folder would overwrite each other's
#: epoch states and weights).
TRAIN_LOCK = ".colonlight-train.lock"


class OutputError(ColonlightError):
    """The output folder cannot be used: it is a file, read-only, not permitted, or held by another batch."""


class OutputBusy(OutputError):
    """Another process holds the output folder's lock."""


_HELD: dict[tuple[int, int], list[int]] = {}  # lock file identity -> [fd, depth], for re-entry in one process
_HELD_GUARD = threading.Lock()


def prepare_output(out_root: Path) -> Path:
    """Create ``out_root`` if needed and check that it is a folder this process can write; OutputError if not."""
    out_root = Path(out_root)
    try:  # Path.exists raises what is not ENOENT-like: a name past NAME_MAX (ENAMETOOLONG) was a traceback
        if os.path.lexists(out_root) and not out_root.exists():
            raise OutputError(f"{out_root}: the output path is a dangling symbolic link (or a link loop)")
        if out_root.exists() and not out_root.is_dir():
            raise OutputError(f"{out_root}: the output path is a file, not a folder")
    except OSError as exc:
        raise OutputError(f"{out_root}: cannot use the output path: {os_error_cause(exc)}") from None
    try:
        out_root.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        if not os.path.lexists(out_root):  # a parent that is a dangling link: mkdir of it found the link there
            raise OutputError(f"{out_root}: a parent of the output folder is a dangling symbolic link") from None
        raise OutputError(f"{out_root}: the output path is a file, not a folder") from None
    except NotADirectoryError:
        raise OutputError(f"{out_root}: a parent of the output folder is a file") from None
    except OSError as exc:
        raise OutputError(f"{out_root}: cannot create the output folder: {os_error_cause(exc)}") from None
    if not os.access(out_root, os.W_OK | os.X_OK):
        try:
            read_only = bool(os.statvfs(out_root).f_flag & os.ST_RDONLY)
        except OSError:
            read_only = False
        why = "read-only file system" if read_only else "permission denied"
        raise OutputError(f"{out_root}: cannot write to the output folder: {why}")
    return out_root


def _holder(fd: int) -> str:
    """Who holds the lock, from what the holder wrote into the lock file."""
    try:
        info: dict[str, Any] = parse_json(os.pread(fd, 4096, 0).decode("utf-8", "replace") or "{}")
    except (OSError, ValueError):
        info = {}
    if not isinstance(info, dict) or "pid" not in info:
        return "another colonlight process"
    since = f", since {info['started']}" if info.get("started") else ""
    return f"colonlight pid {info['pid']} on {info.get('host', '?')}{since}"


@contextmanager
def output_lock(out_root: Path, lock_name: str = OUTPUT_MARKER) -> Iterator[Path]:
    """Hold ``out_root`` (created if needed) for one batch; OutputError if it cannot be used, OutputBusy if another
    process holds it. Yields the folder.

    ``lock_name``: the lock file's name. A training run holds its folder under another name
    (``TRAIN_LOCK``), so that its folder, which holds the rendered training clips, is not taken for an output."""
    out_root = prepare_output(out_root)
    lock_path = out_root / lock_name
    try:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise OutputError(f"{out_root}: cannot write to the output folder: {os_error_cause(exc)}") from None
    ident = (os.fstat(fd).st_dev, os.fstat(fd).st_ino)
    with _HELD_GUARD:
        held = _HELD.get(ident)
        if held is not None:
            os.close(fd)
            held[1] += 1
            fd = -1
    if fd >= 0:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                os.close(fd)
                raise OutputError(f"{out_root}: cannot lock the output folder: {os_error_cause(exc)}") from None
            who = _holder(fd)
            os.close(fd)
            raise OutputBusy(
                f"{out_root}: the output folder is in use by {who}; wait for it to finish or choose another --output"
            ) from None
        record = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "command": [os.fsdecode(a) for a in sys.argv],
        }
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(record, ensure_ascii=True) + "\n").encode("ascii"), 0)
        except OSError:
            pass  # a full disk: the lock holds all the same, only the holder's description is missing
        with _HELD_GUARD:
            _HELD[ident] = [fd, 1]
    try:
        yield out_root
    finally:
        with _HELD_GUARD:
            held = _HELD[ident]
            held[1] -= 1
            if held[1] == 0:
                del _HELD[ident]
                with contextlib.suppress(OSError):
                    os.ftruncate(held[0], 0)  # nobody holds it now (and the folder's bytes do not depend on who did)
                os.close(held[0])  # closing the last descriptor releases the flock


__all__ = ["TRAIN_LOCK", "OutputBusy", "OutputError", "output_lock", "prepare_output"]
