"""The methods' options are declared once (colonlight.methods.options) and every shell is built from it: the CLI's
flags (enhance, stream, evaluate), the service's request schema (OpenAPI, through a real uvicorn) and evaluate show
each option identically, and refuse the same bad value with the same message."""

from __future__ import annotations

import inspect
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import typer
from colonlight_cli.main import app
from colonlight_service.settings import Settings
from typer.testing import CliRunner

from colonlight.errors import MethodOptionError, OptionError
from colonlight.evaluation.runner import method_list
from colonlight.limits import MAX_FPS, MAX_GAMMA, MAX_MODEL_SIZE, MIN_MODEL_SIZE
from colonlight.methods import available_methods
from colonlight.methods.options import OPTIONS, method_kwargs, methods_kwargs, option, request_options

from ...commands import boxed_text
from ...media import make_clip, needs_ffmpeg
from ...service_server import ServiceServer

runner = CliRunner()
COMMANDS = ("enhance", "stream", "evaluate")
#: Values out of range, per option, and a method that takes the option.
BAD_VALUES = [
    ("gamma", "gamma", "0"),
    ("gamma", "gamma", str(MAX_GAMMA + 0.5)),
    ("gamma", "gamma", "bright"),
    ("model_size", "rnn", str(MIN_MODEL_SIZE - 1)),
    ("model_size", "rnn", str(MAX_MODEL_SIZE + 1)),
    ("model_size", "rnn", "huge"),
]


def message_of(name: str, value: str) -> str:
    with pytest.raises(MethodOptionError) as err:
        option(name).parse(value)
    assert err.value.option == name
    return str(err.value)


def command(name: str) -> Any:
    """The click command typer builds for ``name`` (typer's own click classes: no isinstance)."""
    group: Any = typer.main.get_command(app)
    return group.commands[name]


# ------------------------------------------------------------------------------------------------- the declaration


def test_the_declaration_matches_the_methods() -> None:
    """Every option names registered methods; its default is what those methods do when it is not given (device
    excepted: the shells pass theirs, auto, to every method), and each method takes it as a keyword."""
    from colonlight.methods.fixed_gamma import FixedGammaMethod
    from colonlight.methods.rnn import RecurrentGammaMethod
    from colonlight.methods.zerodce import ZeroDceMethod, ZeroDcePlusPlusMethod

    classes = {
        "rnn": RecurrentGammaMethod,
        "gamma": FixedGammaMethod,
        "zerodce": ZeroDceMethod,
        "zerodce++": ZeroDcePlusPlusMethod,
    }
    for opt in OPTIONS:
        assert opt.methods and set(opt.methods) <= set(available_methods()), opt.name
        for name in opt.methods:
            param = inspect.signature(classes[name].__init__).parameters[opt.name]
            assert opt.always or param.default == opt.default, (opt.name, name)


def test_values_are_made_canonical_and_checked() -> None:
    size = option("model_size")
    assert [size.parse(v) for v in (" Auto ", "FULL", "064", 96)] == ["auto", "full", "64", "96"]
    assert option("gamma").parse("0.5") == 0.5 and option("gamma").parse(MAX_GAMMA) == MAX_GAMMA
    assert message_of("model_size", "4") == "model_size must be an integer 8..1024, 'full' or 'auto', got '4'"
    assert message_of("gamma", "0") == "gamma must be a number above 0 and at most 10, got '0'"
    for name, _, value in BAD_VALUES:
        assert isinstance(MethodOptionError(name, "x"), OptionError) and message_of(name, value)


def test_options_go_to_the_methods_that_take_them() -> None:
    assert method_kwargs("rnn", {"model_size": "64"}) == {"model_size": "64", "device": "auto"}
    assert method_kwargs("zerodce", {}, {"device": "cpu", "model_size": "64"}) == {"device": "cpu"}  # fallback
    assert method_kwargs("none", {}, {"device": "cpu", "gamma": "2"}) == {}
    with pytest.raises(MethodOptionError, match=r"gamma applies only to method gamma, not 'rnn'"):
        method_kwargs("rnn", {"gamma": "2"})
    with pytest.raises(MethodOptionError, match="weights fits one method only"):
        methods_kwargs(["rnn", "zerodce"], {"weights": "w.safetensors"})
    both = methods_kwargs(["gamma", "rnn"], {"gamma": "2", "model_size": "full"})
    assert both == {"gamma": {"gamma": 2.0}, "rnn": {"model_size": "full", "device": "auto"}}


# ------------------------------------------------------------------------------------------------- the CLI


@pytest.mark.parametrize("name", COMMANDS)
def test_every_option_is_a_flag_of_the_commands_that_run_methods(name: str) -> None:
    """Same flag, help, environment variable in enhance, stream and evaluate, and in their rendered --help."""
    params = {p.name: p for p in command(name).params}
    shown = boxed_text(runner.invoke(app, [name, "--help"], terminal_width=200).output)
    for opt in OPTIONS:
        param = params[opt.name]
        assert opt.flag in param.opts, (name, opt.name)
        assert getattr(param, "help", None) == opt.description and param.envvar == opt.envvar, (name, opt.name)
        assert opt.flag in shown and boxed_text(opt.description)[:60] in shown, (name, opt.name)


@pytest.mark.parametrize(("name", "method", "value"), BAD_VALUES)
def test_the_cli_refuses_out_of_range_values_with_the_declared_message(
    tmp_path: Path, name: str, method: str, value: str
) -> None:
    for cmd in (["enhance", str(tmp_path), "-o", str(tmp_path / "o")], ["evaluate", str(tmp_path), "--no-colmap"]):
        methods = ["--method" if cmd[0] == "enhance" else "--methods", method]
        result = runner.invoke(app, [*cmd, *methods, option(name).flag, value])
        assert result.exit_code == 2, result.output
        assert message_of(name, value) in boxed_text(result.output) and "Traceback" not in result.output
    assert not (tmp_path / "o").exists()


def test_a_flag_the_methods_do_not_take_is_a_usage_error(tmp_path: Path) -> None:
    enhance = runner.invoke(app, ["enhance", str(tmp_path), "--method", "rnn", "--gamma", "2"])
    assert enhance.exit_code == 2 and "gamma applies only to method gamma, not 'rnn'" in boxed_text(enhance.output)
    evaluate = runner.invoke(app, ["evaluate", str(tmp_path), "--methods", "none,he", "--model-size", "64"])
    assert evaluate.exit_code == 2
    assert "model_size applies only to method rnn, not 'none' or 'he'" in boxed_text(evaluate.output)


@needs_ffmpeg
def test_a_value_from_the_environment_applies_where_it_fits(tmp_path: Path) -> None:
    """COLONLIGHT_GAMMA set for the gamma method does not stop another method's run."""
    clip = make_clip(tmp_path / "c.mp4", n_frames=6, fps=18)
    env = {"COLONLIGHT_GAMMA": "0.5"}
    none = runner.invoke(app, ["enhance", str(clip), "-o", str(tmp_path / "n"), "--method", "none", "-q"], env=env)
    assert none.exit_code == 0, none.output
    gamma = runner.invoke(app, ["enhance", str(clip), "-o", str(tmp_path / "g"), "--method", "gamma", "-q"], env=env)
    record = json.loads((tmp_path / "g" / "c" / "gammas.json").read_text())
    assert gamma.exit_code == 0 and record["parameters"] == {"gamma": 0.5}


def test_evaluate_builds_its_methods_from_the_same_declaration() -> None:
    specs = method_list(
        ["none", "gamma", "rnn"], "authors.pth", chosen=methods_kwargs(["none", "gamma", "rnn"], {"gamma": "2"})
    )
    assert [(s.label, dict(s.options)) for s in specs] == [
        ("none", {}),
        ("gamma", {"gamma": 2.0}),
        ("rnn (ours)", {"device": "auto"}),
        ("rnn (authors)", {"device": "auto", "weights": "authors.pth"}),
    ]
    assert dict(method_list(["zerodce"])[0].options) == {"device": "cpu"}  # the library's default device
    with pytest.raises(OptionError, match="unknown method 'magic'"):
        method_list(["magic"])


# ------------------------------------------------------------------------------------------------- the service


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("options-service") / "data"
    with ServiceServer(data, {"COLONLIGHT_WEIGHTS": str(random_weights), "COLONLIGHT_WORKERS": "1"}) as srv:
        yield srv


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clip(tmp_path_factory.mktemp("options-clip") / "p7.mp4", n_frames=20, fps=25)


def submit(server: ServiceServer, clip: Path, **fields: str) -> httpx.Response:
    files = {"file": (clip.name, clip.read_bytes(), "video/mp4")}
    return httpx.post(server.url + "/v1/jobs", files=files, data=fields, timeout=60)


def wait_done(server: ServiceServer, location: str, timeout: float = 120) -> dict:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = httpx.get(server.url + location, timeout=30).json()
        if job["status"] in ("succeeded", "failed"):
            return job
        time.sleep(0.2)
    raise AssertionError(f"job not finished in {timeout} s")


@needs_ffmpeg
def test_the_openapi_schema_shows_every_request_option_as_declared(server: ServiceServer) -> None:
    spec = httpx.get(server.url + "/openapi.json", timeout=30).json()
    for route in ("/v1/jobs", "/v1/enhance"):
        body = spec["paths"][route]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]
        props = body["properties"]
        for opt in OPTIONS:
            if opt.scope == "request":
                assert props[opt.name] == opt.json_schema(), (route, opt.name)
                assert props[opt.name]["description"] == opt.description
            else:  # the machine's choice: a setting of the server, never a field of a request
                assert opt.name not in props and opt.name in Settings.model_fields, opt.name
    gamma = option("gamma").json_schema()
    assert gamma["exclusiveMinimum"] == 0 and gamma["maximum"] == MAX_GAMMA
    info = httpx.get(server.url + "/v1/info", timeout=30).json()
    assert info["limits"]["max_fps"] == props["fps"]["maximum"] == MAX_FPS  # the page's bound is the API's


@needs_ffmpeg
@pytest.mark.parametrize(("name", "method", "value"), BAD_VALUES)
def test_the_service_refuses_out_of_range_values_with_the_cli_message(
    server: ServiceServer, clip: Path, name: str, method: str, value: str
) -> None:
    r = submit(server, clip, method=method, **{name: value})
    assert r.status_code == 422, r.text
    assert r.json()["code"] == "validation_error" and message_of(name, value) in r.json()["message"]


@needs_ffmpeg
def test_an_option_the_method_does_not_take_is_refused_alike(server: ServiceServer, clip: Path, tmp_path: Path) -> None:
    r = submit(server, clip, method="rnn", gamma="2")
    assert r.status_code == 422 and "gamma applies only to method gamma, not 'rnn'" in r.json()["message"]
    cli = runner.invoke(app, ["enhance", str(clip), "-o", str(tmp_path), "--method", "rnn", "--gamma", "2"])
    assert cli.exit_code == 2 and "gamma applies only to method gamma, not 'rnn'" in boxed_text(cli.output)


@needs_ffmpeg
def test_model_size_auto_is_accepted_by_the_service_and_the_cli(
    server: ServiceServer, clip: Path, tmp_path: Path, random_weights: Path
) -> None:
    """auto: the size the weights were trained at (64 for the test weights), through both shells alike."""
    r = submit(server, clip, model_size="auto", fps="0")
    assert r.status_code == 202, r.text
    job = wait_done(server, r.headers["location"])
    assert job["status"] == "succeeded", job
    served = httpx.get(server.url + job["links"]["gammas"], timeout=30).json()
    args = ["enhance", str(clip), "-o", str(tmp_path), "--weights", str(random_weights), "--fps", "0", "-q"]
    result = runner.invoke(app, [*args, "--model-size", "auto", "--device", "cpu"])
    assert result.exit_code == 0, result.output
    local = json.loads((tmp_path / "p7" / "gammas.json").read_text())
    assert served["parameters"]["model_size"] == local["parameters"]["model_size"] == 64
    assert [f["gamma"] for f in served["frames"]] == [f["gamma"] for f in local["frames"]]


def test_the_server_settings_take_the_declared_values() -> None:
    assert Settings(model_size="auto").model_size == "auto" and Settings(runtime="torch").runtime == "torch"
    for field, value in (("model_size", "4"), ("runtime", "tvm")):
        with pytest.raises(ValueError, match=re.escape(message_of(field, value))):
            Settings(**{field: value})


def test_request_options_are_the_declared_ones() -> None:
    from colonlight_service.request_options import METHOD_FIELDS, JobOptions

    assert tuple(o.name for o in request_options()) == METHOD_FIELDS
    assert set(METHOD_FIELDS) <= set(JobOptions.model_fields)
