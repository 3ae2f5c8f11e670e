"""Live streams: a capture device, a network stream, a paced file or standard input, enhanced frame by frame in
real time with one recurrent state for the whole stream (``colonlight stream``).

Pieces, one module each: ``source`` (what SRC is, opening it with PyAV), ``choice`` (FFmpeg's frame choice decided
as frames arrive), ``handoff`` (the bounded, dropping hand-off between the reader thread and processing),
``reader`` (the reader thread, reconnects), ``outputs`` (frame folder with retention, ``gammas.jsonl``, y4m and
MPEG-TS pipes), ``stats`` (latency in constant memory), ``runner`` (one stream, start to end).
"""

from __future__ import annotations

from .outputs import PIPE_FORMATS, PipeClosed
from .reader import BACKOFF_MAX_S, BACKOFF_START_S
from .runner import DEFAULT_BUFFER, DEFAULT_TIMEOUT_S, LiveStream, OutputPlan, StreamOptions, prepare_output_dir
from .source import SourceSpec, list_devices, parse_source, probe_device
from .stats import StreamSummary

__all__ = [
    "BACKOFF_MAX_S",
    "BACKOFF_START_S",
    "DEFAULT_BUFFER",
    "DEFAULT_TIMEOUT_S",
    "PIPE_FORMATS",
    "LiveStream",
    "OutputPlan",
    "PipeClosed",
    "SourceSpec",
    "StreamOptions",
    "StreamSummary",
    "list_devices",
    "parse_source",
    "prepare_output_dir",
    "probe_device",
]
