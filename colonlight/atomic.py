"""Atomic file writes: a reader (or a resumed run) never sees a half-written file; and the JSON reader that
pairs with the JSON writer, for files that may be damaged.

Every output is written to a temporary name in the destination folder and renamed into place; a rename within one
filesystem is atomic, so after a crash or ``kill -9`` a file either exists complete or not at all.
"""

from __future__ import annotations

import errno
import fcntl
import glob
import json
import os
import secrets
import stat
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .errors import os_error_cause

TMP_MARK = ".colonlight-tmp"
_NAME_TRIES = 100
_UMASK = os.umask(0)
os.umask(_UMASK)


def _temporary_name(dest: Path, suffix: str | None) -> Path:
    """A fresh temporary's name beside ``dest``: hidden, ``TMP_MARK``, ``dest``'s suffix unless one is given."""
    token = secrets.token_hex(6)
    return dest.parent / f".{dest.name}.{token}{TMP_MARK}{dest.suffix if suffix is None else suffix}"


def new_temporary(dest: Path, suffix: str | None = None) -> Path:
    """Create an empty temporary file beside ``dest``, named as a temporary (hidden, ``TMP_MARK``), and return it.

    ``suffix`` (default: that of ``dest``) is kept so that writers choosing a format by extension still work.
    Move it into place with :func:`publish` (or delete it). Created with the usual permissions (0666 less the
    umask), as any output. Not through ``tempfile.mkstemp``: an interrupt (Ctrl-C's or SIGTERM's exception) that
    lands inside it once the file exists leaves a temporary no caller knows the name of; here the name is known
    before the file exists, and an interrupt from then on deletes it.
    """
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(_NAME_TRIES):
        tmp = _temporary_name(dest, suffix)
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666))
        except FileExistsError:  # another writer's (48 random bits: next to never)
            continue
        except BaseException:
            tmp.unlink(missing_ok=True)  # an interrupt once the file existed: it is ours
            raise
        return tmp
    raise FileExistsError(errno.EEXIST, f"no free temporary name after {_NAME_TRIES} tries", str(dest.parent))


def publish(tmp: Path, dest: Path) -> None:
    """Rename the finished temporary ``tmp`` onto ``dest`` (atomic); on failure the temporary is deleted."""
    try:
        os.replace(tmp, dest)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def atomic_path(dest: Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``dest``; rename it onto ``dest`` if the block succeeds, else delete it.

    ``suffix`` (default: that of ``dest``) is kept so that writers choosing a format by extension still work.
    """
    tmp: Path | None = None
    try:  # from the temporary's creation to its rename: an interrupt anywhere in between deletes it
        tmp = new_temporary(dest, suffix)
        yield tmp
        # again: a writer that replaces the file rather than writing into it (safetensors' save_file does)
        # leaves its own private mode, and a trained model's weights would be unreadable to the rest of a lab
        os.chmod(tmp, 0o666 & ~_UMASK)
        publish(tmp, Path(dest))
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise


def write_temporary(dest: Path, data: bytes) -> Path:
    """Write ``data`` to a new temporary beside ``dest``, flushed to disk, and return it (deleted on failure).

    The first half of an atomic write: :func:`publish` is the second. Split so that many temporaries can be
    written in parallel and published in a chosen order (the frame writers of ``colonlight.pipeline``).
    """
    tmp: Path | None = None
    try:
        tmp = new_temporary(dest)
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise
    return tmp


def write_bytes_atomic(dest: Path, data: bytes) -> None:
    """Write ``data`` to ``dest`` atomically, flushed to disk before the rename."""
    tmp: Path | None = None
    try:  # the temporary's name is held until the rename: an interrupt on the way to it deletes it
        tmp = write_temporary(dest, data)
        publish(tmp, Path(dest))
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise


def json_bytes(obj: Any) -> bytes:
    """``obj`` as indented UTF-8 JSON, valid whatever its strings hold.

    File names that are not valid UTF-8 reach Python as lone surrogates (``os.fsdecode``'s surrogate escapes,
    U+DC80..U+DCFF for the bytes 0x80..0xFF), which UTF-8 cannot encode. They are written as JSON escapes
    (``\\udcff``), which every JSON reader accepts and Python's ``json`` reads back to the same string, so
    ``os.fsencode`` gives back the name's original bytes: lossless. Everything else is plain UTF-8.
    """
    return (json.dumps(obj, indent=1, ensure_ascii=False) + "\n").encode("utf-8", "backslashreplace")


def parse_json(text: str | bytes) -> Any:
    """``json.loads``, with JSON nested deeper than the decoder can follow reported as the ``ValueError`` of any
    other malformed JSON.

    The standard decoder recurses once per ``[`` or ``{`` and raises ``RecursionError`` past Python's limit, which
    a caller expecting ``ValueError`` for a damaged file would let escape as a traceback. One place converts it.
    """
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError("JSON nested too deep to decode") from None


#: Why a path that exists is not read as a file (the one wording, wherever colonlight refuses one).
NOT_REGULAR_FILE = "not a regular file (a FIFO, socket or device)"


def read_regular_file(path: Path) -> bytes:
    """The bytes of the regular file at ``path`` (links followed); ``OSError`` if it cannot be read, or if it is a
    FIFO, socket or device. Opened plainly, a FIFO with no writer blocks its reader forever: a ``manifest.json``
    or ``gammas.json`` that was one hung ``colonlight enhance`` without a word, as did ``--camera FIFO``. It is
    opened non-blocking and its type checked on the open file before a byte is read."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):  # what reading a folder has always said
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
        if not stat.S_ISREG(mode):
            raise OSError(errno.EINVAL, NOT_REGULAR_FILE, str(path))
        os.set_blocking(fd, True)
        with open(fd, "rb", closefd=False) as f:
            return f.read()
    finally:
        os.close(fd)


def read_json(path: Path) -> Any:
    """The JSON value in the UTF-8 file at ``path``: ``OSError`` if it cannot be read (or is no regular file:
    :func:`read_regular_file`), ``ValueError`` if it is not JSON (:func:`parse_json`)."""
    return parse_json(read_regular_file(Path(path)).decode("utf-8"))


def write_json_atomic(dest: Path, obj: Any) -> None:
    """Write ``obj`` as indented UTF-8 JSON (:func:`json_bytes`) to ``dest`` atomically."""
    write_bytes_atomic(dest, json_bytes(obj))


def remove_stale_temporaries(folder: Path, recursive: bool = True) -> int:
    """Delete temporaries left in ``folder`` (and, if ``recursive``, below it) by an interrupted run; return how
    many."""
    folder = Path(folder)
    try:
        if not folder.is_dir():
            return 0
    except OSError:  # a name too long for the file system (ENAMETOOLONG), an I/O error: nothing of ours is there
        return 0
    return _delete_files(folder.rglob(f"*{TMP_MARK}*") if recursive else folder.glob(f"*{TMP_MARK}*"))


def remove_stale_temporaries_of(dest: Path) -> int:
    """Delete the temporaries an interrupted write of ``dest`` left beside it (:func:`new_temporary`'s names for
    it, nothing else in its folder); return how many. For outputs written into a folder of the user's (``export
    -o``), where a folder-wide sweep would be too broad."""
    dest = Path(dest)
    try:
        found = list(dest.parent.glob(f".{glob.escape(dest.name)}.*{TMP_MARK}*"))
    except OSError:
        return 0
    return _delete_files(found)


def _delete_files(paths: Iterable[Path]) -> int:
    """Delete those of ``paths`` that are files (a folder of a matching name is not ours); return how many."""
    count = 0
    for p in paths:
        if p.is_file():
            p.unlink(missing_ok=True)
            count += 1
    return count


def parent_problem(path: Path) -> str | None:
    """Why no file or folder can be made at ``path`` because of its parents (the nearest existing one is a file,
    a dangling link, or cannot be looked at), or None. Nothing is created: a command asks before its work, so a
    bad path costs nothing and leaves nothing."""
    for parent in Path(path).parents:
        try:
            if parent.is_dir():
                return None
            if parent.exists():
                return f"{parent} is a file, not a folder"
            if os.path.lexists(parent):
                return f"{parent} is a dangling symbolic link (or a link loop)"
        except OSError as exc:  # a name past NAME_MAX, a folder that cannot be searched
            return f"{parent}: {os_error_cause(exc)}"
    return None


@contextmanager
def files_written_together(folder: Path) -> Iterator[None]:
    """Hold ``folder`` (an exclusive ``flock`` on the folder itself: no lock file is left behind) while a set of
    files that belong together is written into it, as ``export``'s graph and sidecar are: two writers of the same
    names then leave one writer's whole set, never one's graph beside the other's sidecar, and neither removes the
    other's temporaries as stale mid-write. Another process waits its turn (the writes take milliseconds)."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock
