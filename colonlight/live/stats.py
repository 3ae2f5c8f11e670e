"""Latency statistics of a stream in constant memory, however long it runs.

Latencies go into a fixed histogram of 0.1-ms bins up to :data:`HISTOGRAM_S` (longer ones share the last bin;
the maximum is kept exactly), so a day-long stream costs the same 400 KB as a minute. Percentiles are read from
the histogram: exact to 0.1 ms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BIN_S = 1e-4
HISTOGRAM_S = 5.0


class LatencyStats:
    """Count, percentiles and maximum of latencies (seconds)."""

    def __init__(self) -> None:
        self._bins = np.zeros(int(round(HISTOGRAM_S / BIN_S)) + 1, dtype=np.int64)
        self.count = 0
        self.max_s = 0.0
        self._sum = 0.0

    def add(self, seconds: float) -> None:
        seconds = max(0.0, seconds)
        self._bins[min(int(seconds / BIN_S), len(self._bins) - 1)] += 1
        self.count += 1
        self._sum += seconds
        self.max_s = max(self.max_s, seconds)

    def percentile(self, q: float) -> float | None:
        """The ``q``-th percentile (0..100) in seconds (the upper edge of its bin, at most the maximum)."""
        if self.count == 0:
            return None
        rank = max(1, int(np.ceil(q / 100.0 * self.count)))
        k = int(np.searchsorted(np.cumsum(self._bins), rank))
        if k >= len(self._bins) - 1:  # the overflow bin: only the maximum is known
            return self.max_s
        return min((k + 1) * BIN_S, self.max_s)

    @property
    def mean_s(self) -> float | None:
        return self._sum / self.count if self.count else None


@dataclass
class StreamSummary:
    """What a stream did, for the closing summary and ``stream.json``."""

    source: str
    frames_decoded: int = 0  # source frames decoded
    frames_in: int = 0  # frames chosen at the output rate and handed to processing
    frames_out: int = 0  # frames enhanced and written
    frames_dropped: int = 0  # chosen frames discarded because processing was behind (or at a stop)
    frames_damaged: int = 0  # packets the decoder could not use (joined mid-GOP, lost UDP data)
    connections: int = 0
    behind_max_s: float = 0.0  # the most the decoder fell behind the source's own clock (live sources; see reader)
    seconds: float = 0.0
    end: str = ""  # why it ended: source ended | stopped | duration reached | consumer closed the pipe | an error
    error: str | None = None
    latency_p50_ms: float | None = None
    latency_p95_ms: float | None = None
    latency_max_ms: float | None = None
    latency_mean_ms: float | None = None

    def take_latency(self, stats: LatencyStats) -> None:
        def ms(v: float | None) -> float | None:
            return None if v is None else round(v * 1000.0, 2)

        self.latency_p50_ms = ms(stats.percentile(50))
        self.latency_p95_ms = ms(stats.percentile(95))
        self.latency_max_ms = ms(stats.max_s if stats.count else None)
        self.latency_mean_ms = ms(stats.mean_s)
