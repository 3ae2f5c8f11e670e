"""The one JSON reader every damaged-file path goes through (``colonlight.atomic.read_json``/``parse_json``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from colonlight import parse_json, read_json, write_json_atomic

#: deeper than Python's recursion limit: the standard decoder raises RecursionError here, not ValueError
TOO_DEEP = "[" * 100_000


def test_too_deep_json_is_a_value_error_like_any_other_malformed_json() -> None:
    with pytest.raises(RecursionError):  # the reason the reader exists: the standard decoder's own behaviour
        json.loads(TOO_DEEP)
    with pytest.raises(ValueError, match="nested too deep"):
        parse_json(TOO_DEEP)
    with pytest.raises(ValueError, match="nested too deep"):
        parse_json(TOO_DEEP.encode())
    with pytest.raises(ValueError):
        parse_json("{")


def test_read_json_round_trips_what_the_writer_writes(tmp_path: Path) -> None:
    record = {"clip": "a\udcff.mp4", "gamma": [0.5, 1.25], "nested": {"k": None}}
    write_json_atomic(tmp_path / "r.json", record)
    assert read_json(tmp_path / "r.json") == record


def test_read_json_failures_are_os_or_value_errors(tmp_path: Path) -> None:
    with pytest.raises(OSError):
        read_json(tmp_path / "absent.json")
    with pytest.raises(OSError):
        read_json(tmp_path)  # a folder
    (tmp_path / "deep.json").write_text(TOO_DEEP)
    with pytest.raises(ValueError, match="nested too deep"):
        read_json(tmp_path / "deep.json")
    (tmp_path / "latin1.json").write_bytes(b'{"a": "\xff"}')
    with pytest.raises(ValueError):  # not UTF-8: UnicodeDecodeError is a ValueError
        read_json(tmp_path / "latin1.json")
