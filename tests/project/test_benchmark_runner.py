"""The benchmark runner passes options after a benchmark's name to that benchmark only."""

from __future__ import annotations

import pytest

from benchmarks.__main__ import BENCHMARKS, parse


def test_options_follow_their_benchmark() -> None:
    assert parse(["quality_gate", "--json", "g.json", "enhance"]) == [
        ("quality_gate", ["--json", "g.json"]),
        ("enhance", []),
    ]
    assert parse(["objective_landscape"]) == [("objective_landscape", [])]
    assert [name for name, _ in parse([])] == list(BENCHMARKS)


def test_unknown_benchmark_is_a_usage_error() -> None:
    with pytest.raises(SystemExit, match="unknown benchmark 'nope'"):
        parse(["nope"])
    with pytest.raises(SystemExit, match="unknown benchmark '--json'"):
        parse(["--json", "x"])
