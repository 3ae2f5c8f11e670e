"""`--help` says what is true: no value type beside a flag, the demo's real frame rates."""

from __future__ import annotations

import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

runner = CliRunner()


@pytest.mark.parametrize("command", [[], ["enhance"], ["stream"], ["demo"], ["evaluate"], ["info"], ["serve"]])
def test_flags_show_no_bool_type(command: list[str]) -> None:
    result = runner.invoke(app, [*command, "--help"], env={"COLUMNS": "160"})
    assert result.exit_code == 0, result.output
    assert "--help" in result.output
    assert "<bool>" not in result.output
    if command == ["enhance"]:
        assert "<path>" in result.output  # options that take a value keep their type


def test_demo_help_names_the_rate_the_clip_is_rendered_at() -> None:
    text = " ".join(runner.invoke(app, ["demo", "--help"], env={"COLUMNS": "200"}).output.split())
    assert "rendered at 30 fps" in text and "18 of every 30" in text
    assert "frames at 18 fps" not in text
