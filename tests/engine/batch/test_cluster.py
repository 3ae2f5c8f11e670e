"""`colonlight enhance --cluster`: a real Dask scheduler and two worker processes on loopback.

The batch goes through the scheduler to the workers and must give outputs byte-identical to a local run; a worker
killed with SIGKILL in the middle of a clip has that clip retried on the other worker, again byte-identical.
Misconfigured clusters (no scheduler, no worker, workers that do not share the files) fail with one line.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip(
    "distributed", reason="Dask distributed is not installed (the cluster extra: pip install -e '.[cluster]')"
)

from distributed import Client

from colonlight.batch import ClipJob, ClipOutcome, MethodSpec, discover_clips, run_batch
from colonlight.cluster import MARKER_NAME, ClusterRunner, TaskCheck, cluster_task
from colonlight.errors import ColonlightError
from colonlight.pipeline import ClipOptions

from ...media import make_clip, make_image_folder
from ...outputs import output_bytes

COLONLIGHT = [sys.executable, "-c", "from colonlight_cli.main import run; run()"]
START_TIMEOUT = 60  # s, for a scheduler or worker process to come up (first imports can be slow on CI)


def _dask(kind: str) -> list[str]:
    return [sys.executable, "-m", f"distributed.cli.dask_{kind}"]


class LoopbackCluster:
    """A `dask scheduler` and `dask worker` processes on 127.0.0.1, each in its own process group."""

    def __init__(self, root: Path) -> None:
        self.root = root
        root.mkdir(parents=True, exist_ok=True)
        self.procs: list[subprocess.Popen[bytes]] = []
        self.workers: dict[str, subprocess.Popen[bytes]] = {}
        self.count = 0
        file = root / "scheduler.json"
        self.scheduler = self._spawn(
            [
                *_dask("scheduler"),
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(file),
            ],
            "scheduler",
        )
        deadline = time.monotonic() + START_TIMEOUT
        while not file.is_file() or not file.read_text().strip():
            if self.scheduler.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise RuntimeError(f"the scheduler did not start: {self.log('scheduler')}")
            time.sleep(0.1)
        time.sleep(0.05)
        self.address = json.loads(file.read_text())["address"]
        self.client = Client(self.address, timeout=START_TIMEOUT, set_as_default=False)

    def _spawn(self, cmd: list[str], name: str, prefix: list[str] | None = None) -> subprocess.Popen[bytes]:
        env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}  # as a nanny would set
        log = open(self.root / f"{name}.log", "wb")  # noqa: SIM115 - closed with the process
        proc = subprocess.Popen(
            [*(prefix or []), *cmd],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            cwd=self.root,
            start_new_session=True,
        )
        log.close()
        self.procs.append(proc)
        return proc

    def log(self, name: str) -> str:
        path = self.root / f"{name}.log"
        return path.read_text(errors="replace")[-3000:] if path.is_file() else ""

    def start_worker(self, prefix: list[str] | None = None) -> str:
        """Start one single-threaded worker process (no nanny: killing it removes it for good); return its name."""
        self.count += 1
        name = f"w{self.count}"
        self.workers[name] = self._spawn(
            [
                *_dask("worker"),
                self.address,
                "--nthreads",
                "1",
                "--no-nanny",
                "--name",
                name,
                "--no-dashboard",
                "--host",
                "127.0.0.1",
                "--death-timeout",
                "60",
            ],
            name,
            prefix,
        )
        return name

    def alive(self) -> dict[str, str]:
        """Connected workers: name -> address."""
        info = self.client.scheduler_info(n_workers=-1)["workers"]
        return {w["name"]: addr for addr, w in info.items()}

    def ensure_workers(self, n: int = 2) -> dict[str, str]:
        """Start workers until ``n`` are alive and connected; return them (name -> address)."""
        for name, proc in list(self.workers.items()):
            if proc.poll() is not None:
                del self.workers[name]
        while len(self.workers) < n:
            self.start_worker()
        self.client.wait_for_workers(n, timeout=START_TIMEOUT)
        deadline = time.monotonic() + START_TIMEOUT
        while len(alive := self.alive()) != n:  # a killed worker may take a moment to be removed
            assert time.monotonic() < deadline, f"workers: {alive}"
            time.sleep(0.1)
        return alive

    def kill(self, name: str) -> None:
        proc = self.workers.pop(name)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)

    def close(self) -> None:
        client = getattr(self, "client", None)
        if client is not None:
            client.close(timeout=5)
        for proc in reversed(self.procs):
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGTERM)
        for proc in self.procs:
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LoopbackCluster]:
    c = LoopbackCluster(tmp_path_factory.mktemp("dask"))
    try:
        c.ensure_workers(2)
        yield c
    finally:
        c.close()


@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Weights made here (the default model may not be shipped): a fresh GammaNet, saved in our format."""
    import torch

    from colonlight.checkpoint import save_weights
    from colonlight.model import GammaNet

    torch.manual_seed(3)
    path = tmp_path_factory.mktemp("weights") / "t.safetensors"
    save_weights(GammaNet().eval(), path, {"name": "t"})
    return path


@pytest.fixture(scope="module")
def videos(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five clips: four videos long enough to be killed in the middle of (100 frames at 18 fps each), one frame
    folder."""
    root = tmp_path_factory.mktemp("videos")
    for i in range(4):
        make_clip(root / f"site{i % 2}" / f"clip{i}.mp4", n_frames=130 + 10 * i, fps=25, size=(160, 120))
    make_image_folder(root / "seq", n=10)
    return root


def enhance(
    *args: object, env: dict[str, str] | None = None, timeout: float = 120, quiet: bool = True
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*COLONLIGHT, "enhance", *map(str, args), *(["--quiet"] if quiet else [])],
        check=False,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
    )


@pytest.fixture(scope="module")
def local_run(videos: Path, weights: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """The outputs of the same batch run locally (the reference)."""
    out = tmp_path_factory.mktemp("local") / "out"
    proc = enhance(videos, "-o", out, "--weights", weights)
    assert proc.returncode == 0, proc.stderr
    return output_bytes(out)


def _errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.strip()]


# ------------------------------------------------------------------------------------------------ batches


def test_batch_on_cluster_is_byte_identical_to_local(
    cluster: LoopbackCluster, videos: Path, weights: Path, local_run: dict[str, bytes], tmp_path: Path
) -> None:
    cluster.ensure_workers(2)
    out = tmp_path / "out"
    proc = enhance(videos, "-o", out, "--weights", weights, "--cluster", cluster.address)
    assert proc.returncode == 0, proc.stderr
    assert output_bytes(out) == local_run
    assert not list(out.rglob(f"{MARKER_NAME}*")), "check markers must not be left behind"
    # Both workers took part (each holds the model it loaded once, cached per method spec).
    cached = cluster.client.run(lambda: len(__import__("colonlight.jobs").jobs._METHODS))
    assert len(cached) == 2 and all(n >= 1 for n in cached.values()), cached

    # Same resume semantics: a rerun skips every complete clip and changes no output.
    proc = enhance(videos, "-o", out, "--weights", weights, "--cluster", cluster.address)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count("(complete)") == 5, proc.stderr
    assert output_bytes(out) == local_run


def test_relative_paths_are_recorded_as_given_on_the_cluster_too(
    cluster: LoopbackCluster, videos: Path, weights: Path, tmp_path: Path
) -> None:
    """The clips go to the workers with absolute paths (a worker's working folder is not ours), but the records
    name the source as the user gave it, as a local run does: `gammas.json` held "/abs/cwd/../videos/..." there
    against "../videos/..." locally (found by running the README as a new user)."""
    cluster.ensure_workers(2)
    cwd = tmp_path / "work"
    cwd.mkdir()
    rel = os.path.relpath(videos / "site0", cwd)
    outs = {}
    for name, extra in (("local", []), ("cluster", ["--cluster", cluster.address])):
        proc = subprocess.run(
            [*COLONLIGHT, "enhance", rel, "-o", name, "--weights", str(weights), "--quiet", *extra],
            cwd=cwd, capture_output=True, text=True, timeout=120, check=False,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        outs[name] = output_bytes(cwd / name)
    assert outs["cluster"] == outs["local"]
    manifest = json.loads(outs["local"]["manifest.json"])
    assert {c["source"] for c in manifest["clips"]} == {f"{rel}/clip0.mp4", f"{rel}/clip2.mp4"}


def _executing(cluster: LoopbackCluster, address: str) -> list[str]:
    """Clip names of the tasks a worker is executing now (task keys end with the clip name)."""

    def keys(dask_worker) -> list[str]:  # type: ignore[no-untyped-def]
        return [str(ts.key) for ts in dask_worker.state.executing]

    try:
        found = cluster.client.run(keys, workers=[address], on_error="return")
    except Exception:  # noqa: BLE001
        return []
    names = found.get(address)
    return [k.split("-", 3)[3] for k in names] if isinstance(names, list) else []


def test_worker_killed_mid_clip_is_retried_elsewhere(
    cluster: LoopbackCluster, videos: Path, weights: Path, local_run: dict[str, bytes], tmp_path: Path
) -> None:
    workers = cluster.ensure_workers(2)
    victim = min(workers)
    out = tmp_path / "out"
    cmd = [
        *COLONLIGHT,
        "enhance",
        str(videos),
        "-o",
        str(out),
        "--weights",
        str(weights),
        "--cluster",
        cluster.address,
        "--quiet",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        killed_clip = None
        deadline = time.monotonic() + 60
        while killed_clip is None and time.monotonic() < deadline and proc.poll() is None:
            for clip in _executing(cluster, workers[victim]):
                frames = out / clip / "frames"
                # in the middle of a video clip: some frames written, the clip not complete
                if clip.startswith("site") and frames.is_dir() and len(list(frames.glob("*.png"))) >= 3:
                    assert not (out / clip / "gammas.json").exists()
                    cluster.kill(victim)
                    killed_clip = clip
                    break
            time.sleep(0.02)
        assert killed_clip is not None, "never caught the worker in the middle of a clip"
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    assert victim not in cluster.alive()
    assert output_bytes(out) == local_run, f"outputs differ after killing {victim} during {killed_clip}"
    assert not list(out.rglob("*.colonlight-tmp*")) and not list(out.rglob(f"{MARKER_NAME}*"))


def test_shipped_default_with_video_on_cluster_is_byte_identical_to_local(
    cluster: LoopbackCluster, videos: Path, tmp_path: Path
) -> None:
    """What users run: the shipped default (curve head, delta input, tone matching, scene cuts) and enhanced.mp4,
    whose encoder settings keep its bytes the same in any process (x264 threads, no macroblock tree)."""
    cluster.ensure_workers(2)
    local, remote = tmp_path / "local", tmp_path / "cluster"
    proc = enhance(videos / "site0", "-o", local, "--video")
    assert proc.returncode == 0, proc.stderr
    proc = enhance(videos / "site0", "-o", remote, "--video", "--cluster", cluster.address)
    assert proc.returncode == 0, proc.stderr
    expected = output_bytes(local)
    assert sum(name.endswith("enhanced.mp4") for name in expected) == 2, sorted(expected)
    assert output_bytes(remote) == expected


def test_missing_and_broken_clips_fail_as_in_a_local_run(
    cluster: LoopbackCluster, weights: Path, tmp_path: Path
) -> None:
    cluster.ensure_workers(2)
    make_clip(tmp_path / "in" / "ok.mp4", n_frames=20, fps=25)
    (tmp_path / "in" / "broken.mp4").write_bytes(b"\0" * 100)
    spec = MethodSpec.of("rnn", weights=str(weights), device="cpu")
    runs = {}
    for where in ("local", "remote"):
        jobs = discover_clips([tmp_path / "in", tmp_path / "nowhere.mp4"], tmp_path / where)
        runs[where] = run_batch(
            jobs,
            spec,
            ClipOptions(),
            tmp_path / where,
            cluster=cluster.address if where == "remote" else None,
        )
    strip = [(o.name, o.source, o.status, o.frames, o.error) for o in runs["local"]]
    assert [(o.name, o.source, o.status, o.frames, o.error) for o in runs["remote"]] == strip
    assert [s for _, _, s, _, _ in strip] == ["failed", "done", "failed"]
    assert output_bytes(tmp_path / "remote") == output_bytes(tmp_path / "local")


def test_runner_api_and_progress_events(cluster: LoopbackCluster, videos: Path, weights: Path, tmp_path: Path) -> None:
    """The service's entry (ClusterRunner.submit -> future of a ClipOutcome) and the batch's progress events."""
    cluster.ensure_workers(2)
    spec = MethodSpec.of("rnn", weights=str(weights), device="cpu")
    opts = ClipOptions()
    jobs = discover_clips([videos / "seq", videos / "site0"], tmp_path / "out")
    with ClusterRunner(cluster.address) as runner:
        futures = [runner.submit(job, spec, opts) for job in jobs]
        outcomes = [f.result(timeout=60) for f in futures]
    assert all(isinstance(o, ClipOutcome) and o.status == "done" for o in outcomes), outcomes

    events: list[tuple[str, str]] = []
    seen: list[ClipOutcome] = []
    result = run_batch(
        jobs,
        spec,
        opts,
        tmp_path / "again",
        overwrite=True,
        cluster=cluster.address,
        progress=lambda ev, clip, data: events.append((ev, clip)),
        on_outcome=seen.append,
    )
    assert [o.name for o in result] == [j.name for j in jobs] and len(seen) == len(jobs)
    for job in jobs:
        mine = [e for e, c in events if c == job.name]
        assert mine[0] == "start" and mine[-1] == "end" and mine.count("end") == 1, events
    assert (tmp_path / "again" / "manifest.json").is_file()


# ------------------------------------------------------------------------------------------------ failures


def _enhance_on_unreachable_cluster(
    tmp_path: Path, weights: Path, quiet: bool = True
) -> tuple[subprocess.CompletedProcess[str], int]:
    """``enhance --cluster`` of a 3-frame folder at a loopback port that nothing listens on -> (run, port)."""
    import socket

    make_image_folder(tmp_path / "seq", n=3)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = enhance(
        tmp_path / "seq",
        "-o",
        tmp_path / "out",
        "--weights",
        weights,
        "--cluster",
        f"tcp://127.0.0.1:{port}",
        env={"COLONLIGHT_CLUSTER_TIMEOUT": "1"},
        quiet=quiet,
    )
    return proc, port


def test_unreachable_scheduler_is_one_line(tmp_path: Path, weights: Path) -> None:
    t0 = time.monotonic()
    proc, port = _enhance_on_unreachable_cluster(tmp_path, weights)
    assert proc.returncode == 1
    assert time.monotonic() - t0 < 30
    lines = _errors(proc.stderr)
    assert len(lines) == 1 and "cannot reach the Dask scheduler" in lines[0] and str(port) in lines[0], proc.stderr


def test_unreachable_scheduler_draws_no_empty_bar(tmp_path: Path, weights: Path) -> None:
    """Without --quiet the error line is all there is: the bars are drawn from the first clip on, and a batch
    that cannot reach its cluster has none."""
    proc, _ = _enhance_on_unreachable_cluster(tmp_path, weights, quiet=False)
    assert proc.returncode == 1
    assert "cannot reach the Dask scheduler" in proc.stdout + proc.stderr
    assert "0/1" not in proc.stdout + proc.stderr, proc.stdout + proc.stderr


def _unshare_works() -> bool:
    if not shutil.which("unshare") or os.geteuid() != 0:
        return False
    probe = subprocess.run(["unshare", "--mount", "--propagation", "private", "true"], check=False, capture_output=True)
    return probe.returncode == 0


def test_no_worker_then_a_worker_without_the_shared_files(tmp_path: Path, weights: Path) -> None:
    """A scheduler with no worker, then one worker in a private mount namespace where our folder is empty."""
    data = tmp_path / "data"
    make_image_folder(data / "seq", n=4)
    args = [data / "seq", "-o", data / "out", "--weights", weights]
    c = LoopbackCluster(tmp_path / "dask")
    try:
        with (
            pytest.raises(ColonlightError, match="no Dask worker is connected"),
            ClusterRunner(c.address, 1) as runner,
        ):
            runner.check(discover_clips([data / "seq"], data / "out"), MethodSpec.of("none"))

        if not _unshare_works():
            pytest.skip("needs root and unshare(1) to give a worker a private view of the filesystem")
        # The worker sees an empty tmpfs where `data` is: no inputs, no output folder (weights stay visible).
        c.start_worker(
            prefix=[
                "unshare",
                "--mount",
                "--propagation",
                "private",
                "sh",
                "-c",
                f'mount -t tmpfs none "{data}" && exec "$0" "$@"',
            ]
        )
        c.client.wait_for_workers(1, timeout=START_TIMEOUT)
        proc = enhance(*args, "--cluster", c.address)
        assert proc.returncode == 1, proc.stderr
        lines = _errors(proc.stderr)
        assert len(lines) == 1 and "cannot see the output folder" in lines[0] and "shared filesystem" in lines[0], lines
        assert not list((data / "out").rglob(f"{MARKER_NAME}*"))

        # A clip submitted directly (as the service does, without the batch's pre-flight) fails on its own.
        job = ClipJob(source=data / "seq", name="seq", out_dir=data / "out" / "seq")
        spec = MethodSpec.of("rnn", weights=str(weights), device="cpu")
        with ClusterRunner(c.address) as runner:
            outcome = runner.submit(job, spec, ClipOptions()).result(timeout=60)
        assert outcome.status == "failed" and "not found on worker" in (outcome.error or ""), outcome
    finally:
        c.close()


def test_task_checks_in_process(tmp_path: Path) -> None:
    """The per-task checks, outside any cluster: a missing output folder or source, outputs not visible here."""
    src = tmp_path / "seq"
    make_image_folder(src, n=3)
    spec = MethodSpec.of("none")
    job = ClipJob(source=src, name="seq", out_dir=tmp_path / "out" / "seq")
    o = cluster_task(job, spec, ClipOptions(), False, TaskCheck(True, True, None, None))
    assert o.status == "failed" and "does not see this output folder" in (o.error or "")

    job.out_dir.mkdir(parents=True)
    o = cluster_task(job, spec, ClipOptions(), False, TaskCheck(True, True, None, None))
    assert o.status == "done" and o.frames == 3

    gone = ClipJob(source=tmp_path / "gone", name="gone", out_dir=tmp_path / "out" / "gone")
    o = cluster_task(gone, spec, ClipOptions(), False, TaskCheck(False, True, None, None))
    assert o.status == "failed" and "not found on worker" in (o.error or "")

    model = {"name": "x", "sha256": "0" * 64}
    o = cluster_task(job, spec, ClipOptions(), False, TaskCheck(True, True, model, None))
    assert o.status == "failed" and "give every worker the same weights" in (o.error or "")

    with pytest.raises(ColonlightError, match="not a Dask scheduler address"):
        ClusterRunner("nonsense://here")


def test_service_dispatches_jobs_to_the_cluster(cluster: LoopbackCluster, weights: Path, tmp_path: Path) -> None:
    """`COLONLIGHT_CLUSTER`: the same API, the clip enhanced by a Dask worker, the same bytes as a local job."""
    import httpx

    from ...service_server import ServiceServer

    clip = make_clip(tmp_path / "p7.mp4", n_frames=50, fps=25, size=(160, 120))
    results = {}
    for label, extra in (("cluster", {"COLONLIGHT_CLUSTER": cluster.address}), ("local", {})):
        env = {"COLONLIGHT_WEIGHTS": str(weights), "COLONLIGHT_WORKERS": "2", **extra}
        with ServiceServer(tmp_path / f"svc-{label}", env) as srv, httpx.Client(base_url=srv.url, timeout=60) as client:
            with open(clip, "rb") as fh:
                r = client.post("/v1/jobs", files={"file": ("p7.mp4", fh, "video/mp4")}, data={"fps": "18"})
            assert r.status_code == 202, r.text
            deadline = time.monotonic() + 90
            while (job := client.get(r.headers["location"]).json())["status"] not in ("succeeded", "failed"):
                assert time.monotonic() < deadline, job
                time.sleep(0.2)
            assert job["status"] == "succeeded", job
            gammas = client.get(job["links"]["gammas"]).json()
            assert gammas["frame_count"] == 36 and gammas["model"]["name"] == "t"
            results[label] = ([f["gamma"] for f in gammas["frames"]], client.get(job["links"]["video"]).content)
    assert results["cluster"] == results["local"]
