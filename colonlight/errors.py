"""Exceptions raised by the colonlight engine.

Hierarchy::

    ColonlightError              base of every expected failure; its message is one line for the user
    ├── InputError               a clip or frame folder that cannot be read (names the file and the cause)
    │   └── FrameTooLargeError   its frames exceed the pixel cap (known from the header, before decoding)
    │   └── FrameShapeError      a frame a method cannot take (not HxWx3 uint8, a size that changed mid-stream)
    ├── OptionError              a bad option value: a method's (unknown name, out of range), a clip's, a stream's
    │   ├── MethodOptionError    a declared method option (colonlight.methods.options) out of range or not applicable
    │   └── MissingExtraError    a command or option whose optional extra is not installed (usage: exit status 2)
    ├── CheckpointError          a weights file that is missing, corrupt, truncated or of an unknown format
    └── DeviceError              a requested device (e.g. ``cuda:1``) that this machine does not have

``OptionError`` and ``FrameShapeError`` are also ``ValueError``s, as these failures were before they had a type
of their own: callers that catch ``ValueError`` keep working.

Shells (CLI, service) catch ``ColonlightError`` and show its message without a traceback; anything else is a bug.
"""

from __future__ import annotations

import errno


class ColonlightError(Exception):
    """Base class of expected failures; ``str(err)`` is a one-line message for the user."""


class InputError(ColonlightError):
    """An input clip, image folder or frame that cannot be used."""


class FrameTooLargeError(InputError):
    """A clip whose frames have more pixels than the cap allows; raised from the header, before decoding.

    ``width``, ``height`` and ``max_pixels`` let a shell answer in its own terms (the service: 413/422).
    """

    def __init__(self, path: object, width: int, height: int, max_pixels: int) -> None:
        self.path, self.width, self.height, self.max_pixels = path, width, height, max_pixels
        size = f"{width}x{height} ({width * height / 1e6:.1f} Mpx)" if width and height else "unknown size"
        super().__init__(
            f"{path}: frames of {size} exceed the pixel cap of {max_pixels} "
            f"({max_pixels / 1e6:.1f} Mpx; raise it with COLONLIGHT_MAX_PIXELS or --max-pixels)"
        )


class FrameShapeError(InputError, ValueError):
    """A frame that a method cannot take: its shape or type, or a size other than the stream's first frame."""


class OptionError(ColonlightError, ValueError):
    """An option value that cannot be used (a method, clip or stream option): the message names it and the range."""


class MissingExtraError(OptionError):
    """A command or option whose optional extra is not installed (``--cluster``, ``export``, ``evaluate``,
    ``--runtime onnxruntime``): found before any work, so the shells treat it as a usage error (exit status 2);
    the message names the packages and the command that installs them (:mod:`colonlight.extras`)."""


class MethodOptionError(OptionError):
    """A method option a shell took from its user (``--gamma``, a request's ``gamma``) that cannot be used.

    ``option`` is the option's name (``"gamma"``), so that a shell can point at its own spelling (``--gamma``);
    the message is the same in every shell.
    """

    def __init__(self, option: str, message: str) -> None:
        self.option = option
        super().__init__(message)


class CheckpointError(ColonlightError):
    """A checkpoint that cannot be loaded."""


class DeviceError(ColonlightError):
    """A requested compute device that is not available."""


def os_error_cause(exc: OSError) -> str:
    """What an ``OSError`` means to the user, in a few words: one wording for every place that names a path it
    could not use (a link loop is no "no such file", the cause the bare errno text would give)."""
    if exc.errno == errno.ELOOP:
        return "symbolic link loop"
    if exc.errno == errno.ENOENT:
        return "not found (a dangling link, or moved or deleted?)"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return "permission denied"
    if exc.errno == errno.EROFS:
        return "read-only file system"
    if exc.errno == errno.ENOSPC:
        return "no space left on device"
    if exc.errno == errno.ENOTDIR:
        return "a parent of it is a file, not a folder"
    return exc.strerror or str(exc)


#: Words of a loader's error that mean memory ran short (a limit such as ``ulimit -v``), not a missing package.
_SHORT_OF_MEMORY = ("failed to map segment", "cannot allocate memory", "out of memory")


def load_failure_cause(exc: BaseException) -> str:
    """What an import that failed says, in one line, with a hint when memory ran short: under a limit such as
    ``ulimit -v`` torch's and FFmpeg's libraries fail to map, which reads like a broken installation."""
    cause = " ".join(f"{type(exc).__name__}: {exc}".split()) if str(exc) else type(exc).__name__
    if isinstance(exc, MemoryError) or any(word in cause.lower() for word in _SHORT_OF_MEMORY):
        cause += " (too little memory to load the libraries: a limit such as `ulimit -v`?)"
    return cause


def resource_shortage(exc: BaseException) -> str | None:
    """The words for an exception that means the machine ran short (memory, or a thread that could not start),
    else None: such a clip failed for want of resources, not by an internal error worth a bug report."""
    if isinstance(exc, MemoryError):
        return "out of memory (too little memory, or a limit such as `ulimit -v`)"
    if isinstance(exc, RuntimeError) and "can't start new thread" in str(exc):
        return "cannot start a thread (too little memory, or a limit such as `ulimit -u` or `ulimit -v`)"
    return None
