"""Counters of the running server, rendered in the Prometheus text format (no client library needed).

Counters restart from zero with the process, as Prometheus expects; gauges (jobs by status, queue depth) are
read live when /metrics is scraped.
"""

from __future__ import annotations

import os
import resource
import threading
from collections import defaultdict

BUCKETS = (0.5, 1, 2, 5, 10, 30, 60, 120, 300, 600, 1800, 3600)


class Metrics:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.submitted = 0
        self.sync_requests: dict[str, int] = defaultdict(int)
        self.finished: dict[str, int] = defaultdict(int)
        self.rejected: dict[str, int] = defaultdict(int)
        self.frames = 0
        self.seconds_sum = 0.0
        self.seconds_count = 0
        self.bucket_counts = [0] * len(BUCKETS)

    def inc(self, name: str, label: str | None = None, by: int = 1) -> None:
        with self._lock:
            if label is None:
                setattr(self, name, getattr(self, name) + by)
            else:
                getattr(self, name)[label] += by

    def observe_job(self, status: str, seconds: float) -> None:
        with self._lock:
            self.finished[status] += 1
            self.seconds_sum += seconds
            self.seconds_count += 1
            for i, bound in enumerate(BUCKETS):
                if seconds <= bound:
                    self.bucket_counts[i] += 1

    def render(self, jobs_by_status: dict[str, int], queue_depth: int, running: int, workers: int,
               admitted: int, capacity: int, ready: bool) -> str:
        out: list[str] = []

        def metric(name: str, kind: str, help_text: str, samples: list[tuple[str, float]]) -> None:
            out.append(f"# HELP {name} {help_text}")
            out.append(f"# TYPE {name} {kind}")
            for labels, value in samples:
                out.append(f"{name}{labels} {value:g}" if isinstance(value, float) else f"{name}{labels} {value}")

        with self._lock:
            metric("colonlight_jobs", "gauge", "Jobs on record by status.",
                   [(f'{{status="{s}"}}', n) for s, n in sorted(jobs_by_status.items())])
            metric("colonlight_queue_depth", "gauge", "Jobs waiting for a worker.", [("", queue_depth)])
            metric("colonlight_jobs_running", "gauge", "Jobs being processed now.", [("", running)])
            metric("colonlight_workers", "gauge", "Clips processed at once at most.", [("", workers)])
            metric("colonlight_admitted", "gauge", "Jobs admitted now (queued, running or uploading).", [("", admitted)])
            metric("colonlight_capacity", "gauge", "Jobs admitted at once at most (workers + queue size).", [("", capacity)])
            metric("colonlight_ready", "gauge", "1 when the model is loaded and work is accepted.", [("", int(ready))])
            metric("colonlight_jobs_submitted_total", "counter", "Jobs accepted by POST /v1/jobs.", [("", self.submitted)])
            metric("colonlight_jobs_finished_total", "counter", "Jobs finished, by outcome.",
                   [(f'{{status="{s}"}}', n) for s, n in sorted(self.finished.items())] or [('{status="succeeded"}', 0)])
            metric("colonlight_sync_requests_total", "counter", "POST /v1/enhance requests by outcome.",
                   [(f'{{outcome="{s}"}}', n) for s, n in sorted(self.sync_requests.items())] or [('{outcome="ok"}', 0)])
            metric("colonlight_requests_rejected_total", "counter", "Uploads refused, by reason.",
                   [(f'{{reason="{s}"}}', n) for s, n in sorted(self.rejected.items())] or [('{reason="queue_full"}', 0)])
            metric("colonlight_frames_processed_total", "counter", "Enhanced frames written.", [("", self.frames)])
            out.append("# HELP colonlight_processing_seconds Wall time of finished clips.")
            out.append("# TYPE colonlight_processing_seconds histogram")
            for bound, n in zip(BUCKETS, self.bucket_counts):
                out.append(f'colonlight_processing_seconds_bucket{{le="{bound:g}"}} {n}')
            out.append(f'colonlight_processing_seconds_bucket{{le="+Inf"}} {self.seconds_count}')
            out.append(f"colonlight_processing_seconds_sum {self.seconds_sum:.6f}")
            out.append(f"colonlight_processing_seconds_count {self.seconds_count}")
        rss, peak = memory_bytes()
        metric("process_resident_memory_bytes", "gauge", "Resident memory of the server process.", [("", rss)])
        metric("process_peak_resident_memory_bytes", "gauge", "Peak resident memory of the server process.", [("", peak)])
        return "\n".join(out) + "\n"


def memory_bytes() -> tuple[int, int]:
    """(current RSS, peak RSS) of this process in bytes."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    try:
        with open(f"/proc/{os.getpid()}/statm") as fh:
            rss = int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        rss = peak
    return rss, peak
