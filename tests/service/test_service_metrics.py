"""The service's counters through ``prometheus_client``: the exposition a scrape gets, and counts summed over
several worker processes (its multiprocess mode, as under ``uvicorn --workers N``). No server needed: the
/metrics route itself is exercised by test_service.py and the limits tests."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from colonlight_service.metrics import Metrics
from prometheus_client.parser import text_string_to_metric_families


def _samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def test_render_is_standard_exposition_with_live_gauges() -> None:
    m = Metrics()
    m.inc("submitted")
    m.inc("frames", by=36)
    m.inc("rejected", "not_video")
    m.observe_job("succeeded", 1.5)
    text = m.render({"queued": 1, "succeeded": 2}, 1, 0, 2, 1, 10, True)
    s = _samples(text)  # parses as the text format (the parser raises on anything else)
    assert s[("colonlight_jobs_submitted_total", ())] == 1
    assert s[("colonlight_frames_processed_total", ())] == 36
    assert s[("colonlight_requests_rejected_total", (("reason", "not_video"),))] == 1
    assert s[("colonlight_requests_rejected_total", (("reason", "queue_full"),))] == 0  # shown before any refusal
    assert s[("colonlight_jobs_finished_total", (("status", "succeeded"),))] == 1
    assert s[("colonlight_processing_seconds_count", ())] == 1
    assert s[("colonlight_processing_seconds_bucket", (("le", "2.0"),))] == 1
    assert s[("colonlight_processing_seconds_bucket", (("le", "1.0"),))] == 0
    assert s[("colonlight_jobs", (("status", "succeeded"),))] == 2
    assert s[("colonlight_workers", ())] == 2 and s[("colonlight_ready", ())] == 1
    assert s[("process_peak_resident_memory_bytes", ())] > 0
    assert "_created" not in text
    assert "# TYPE colonlight_processing_seconds histogram" in text


def test_two_servers_in_one_process_count_apart() -> None:
    a, b = Metrics(), Metrics()
    a.inc("submitted")
    assert _samples(b.render({}, 0, 0, 1, 0, 1, False))[("colonlight_jobs_submitted_total", ())] == 0


WORKER = """
import sys
from colonlight_service.metrics import Metrics
m = Metrics()
m.inc("frames", by=int(sys.argv[1]))
m.inc("rejected", "too_large")
if sys.argv[2] == "render":
    print(m.render({}, 0, 0, 1, 0, 1, True))
"""


def test_counts_of_several_worker_processes_are_summed(tmp_path: Path) -> None:
    env = {**os.environ, "PROMETHEUS_MULTIPROC_DIR": str(tmp_path)}
    for n in (5, 7):
        subprocess.run([sys.executable, "-c", WORKER, str(n), "-"], env=env, check=True, timeout=60)
    out = subprocess.run(
        [sys.executable, "-c", WORKER, "11", "render"], env=env, check=True, timeout=60, capture_output=True, text=True
    ).stdout
    s = _samples(out)
    assert s[("colonlight_frames_processed_total", ())] == 5 + 7 + 11
    assert s[("colonlight_requests_rejected_total", (("reason", "too_large"),))] == 3
    assert s[("colonlight_workers", ())] == 1  # the live gauges: the answering worker's
