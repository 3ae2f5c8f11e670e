"""Counters of the running server, exposed through ``prometheus_client`` in the Prometheus text format.

Why the library: its exposition is the standard format (escaping, ``+Inf``, histogram series) and its
multiprocess mode keeps counters right when the app runs in several uvicorn worker processes: with
``PROMETHEUS_MULTIPROC_DIR`` set (an empty folder, before the server starts), every worker writes its counts
there and a scrape of any worker sums them all. Counters restart from zero with the server, as Prometheus expects;
gauges (jobs by status, queue depth, readiness, memory) are read live when /metrics is scraped, from the worker
that answers.
"""

from __future__ import annotations

import os
import resource
import threading
from collections.abc import Iterator
from typing import Any

import prometheus_client
from prometheus_client import CollectorRegistry, Counter, Histogram, generate_latest, multiprocess
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector

BUCKETS = (0.5, 1, 2, 5, 10, 30, 60, 120, 300, 600, 1800, 3600)
#: ``Content-Type`` of the exposition (text format 0.0.4).
CONTENT_TYPE = prometheus_client.CONTENT_TYPE_LATEST
MULTIPROC_ENV = "PROMETHEUS_MULTIPROC_DIR"

prometheus_client.disable_created_metrics()  # no ``*_created`` series: the samples stay those of the counters


class Metrics:
    """The server's counters; :meth:`render` adds the live gauges and returns the exposition text."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._live: dict[str, Any] = {}
        self.registry = CollectorRegistry(auto_describe=True)
        r = self.registry
        self.submitted = Counter("colonlight_jobs_submitted_total", "Jobs accepted by POST /v1/jobs.", registry=r)
        self.finished = Counter("colonlight_jobs_finished_total", "Jobs finished, by outcome.", ["status"], registry=r)
        self.sync_requests = Counter(
            "colonlight_sync_requests_total", "POST /v1/enhance requests by outcome.", ["outcome"], registry=r
        )
        self.rejected = Counter(
            "colonlight_requests_rejected_total", "Uploads refused, by reason.", ["reason"], registry=r
        )
        self.frames = Counter("colonlight_frames_processed_total", "Enhanced frames written.", registry=r)
        self.seconds = Histogram(
            "colonlight_processing_seconds", "Wall time of finished clips.", buckets=BUCKETS, registry=r
        )
        # the samples a scrape shows before anything happened (as the hand-written text did)
        self.finished.labels("succeeded")
        self.sync_requests.labels("ok")
        self.rejected.labels("queue_full")
        r.register(_LiveGauges(self._live, self._lock))

    def inc(self, name: str, label: str | None = None, by: int = 1) -> None:
        counter = getattr(self, name)
        (counter if label is None else counter.labels(label)).inc(by)

    def observe_job(self, status: str, seconds: float) -> None:
        self.finished.labels(status).inc()
        self.seconds.observe(seconds)

    def render(
        self,
        jobs_by_status: dict[str, int],
        queue_depth: int,
        running: int,
        workers: int,
        admitted: int,
        capacity: int,
        ready: bool,
    ) -> str:
        with self._lock:
            self._live.update(
                jobs=jobs_by_status,
                queue_depth=queue_depth,
                running=running,
                workers=workers,
                admitted=admitted,
                capacity=capacity,
                ready=ready,
            )
            if os.environ.get(MULTIPROC_ENV):  # the counters of every worker process, summed
                registry = CollectorRegistry()
                multiprocess.MultiProcessCollector(registry)
                registry.register(_LiveGauges(dict(self._live), threading.Lock()))
            else:
                registry = self.registry
        return generate_latest(registry).decode("utf-8")


class _LiveGauges(Collector):
    """The gauges read at scrape time (the values :meth:`Metrics.render` was given, and this process's memory)."""

    def __init__(self, live: dict[str, Any], lock: threading.Lock) -> None:
        self.live, self.lock = live, lock

    def collect(self) -> Iterator[GaugeMetricFamily]:
        live = self.live
        if not live:
            return
        jobs = GaugeMetricFamily("colonlight_jobs", "Jobs on record by status.", labels=["status"])
        for status, n in sorted(live["jobs"].items()):
            jobs.add_metric([status], n)
        yield jobs
        for name, key, help_text in (
            ("colonlight_queue_depth", "queue_depth", "Jobs waiting for a worker."),
            ("colonlight_jobs_running", "running", "Jobs being processed now."),
            ("colonlight_workers", "workers", "Clips processed at once at most."),
            ("colonlight_admitted", "admitted", "Jobs admitted now (queued, running or uploading)."),
            ("colonlight_capacity", "capacity", "Jobs admitted at once at most (workers + queue size)."),
            ("colonlight_ready", "ready", "1 when the model is loaded and work is accepted."),
        ):
            yield GaugeMetricFamily(name, help_text, value=int(live[key]))
        rss, peak = memory_bytes()
        yield GaugeMetricFamily("process_resident_memory_bytes", "Resident memory of the server process.", value=rss)
        yield GaugeMetricFamily(
            "process_peak_resident_memory_bytes", "Peak resident memory of the server process.", value=peak
        )


def memory_bytes() -> tuple[int, int]:
    """(current RSS, peak RSS) of this process in bytes."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    try:
        with open(f"/proc/{os.getpid()}/statm") as fh:
            rss = int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        rss = peak
    return rss, peak
