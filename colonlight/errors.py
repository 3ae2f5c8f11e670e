"""Exceptions raised by the colonlight engine.

Hierarchy::

    ColonlightError              base of every expected failure; its message is one line for the user
    ├── InputError               a clip or frame folder that cannot be read (names the file and the cause)
    ├── CheckpointError          a weights file that is missing, corrupt, truncated or of an unknown format
    └── DeviceError              a requested device (e.g. ``cuda:1``) that this machine does not have

Shells (CLI, service) catch ``ColonlightError`` and show its message without a traceback; anything else is a bug.
"""

from __future__ import annotations


class ColonlightError(Exception):
    """Base class of expected failures; ``str(err)`` is a one-line message for the user."""


class InputError(ColonlightError):
    """An input clip, image folder or frame that cannot be used."""


class CheckpointError(ColonlightError):
    """A checkpoint that cannot be loaded."""


class DeviceError(ColonlightError):
    """A requested compute device that is not available."""
