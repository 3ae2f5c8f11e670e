"""`colonlight evaluate` end to end: a user's folder (a real video and a corrupt file), the synthetic benchmark,
usage errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.video import VideoWriter
from tests.engine.evaluation.test_evaluation import box_clip

runner = CliRunner()


def test_folder_with_a_video_and_a_corrupt_file(tmp_path: Path) -> None:
    """The readable clip is evaluated and reported; the corrupt one is one line; the exit code says 1."""
    clips = tmp_path / "clips"
    clips.mkdir()
    with VideoWriter(clips / "good.mp4", fps=18) as w:
        for f in box_clip(n=10).frames:
            w.write(f)
    (clips / "bad.mp4").write_bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    out = tmp_path / "out"
    result = runner.invoke(app, ["evaluate", str(clips), "-o", str(out), "--methods", "none,he,rnn", "-q"])
    assert result.exit_code == 1, result.output
    bad_lines = [line for line in result.output.splitlines() if "bad.mp4" in line]
    assert len(bad_lines) == 1 and "failed" in bad_lines[0]
    assert "Traceback" not in result.output
    for name in ("report.html", "results.json", "table.md", "table.csv", "clips.csv"):
        assert (out / name).is_file(), name
    assert str(out / "report.html") in result.output.replace("\n", "")
    record = json.loads((out / "results.json").read_text())
    assert [c["name"] for c in record["clips"]] == ["good"]
    assert record["failures"][0]["clip"] == "bad"
    good = record["clips"][0]
    assert good["correspondence"] == "optical flow" and good["info"]["frames"] == 10
    res = good["results"]
    assert set(res) == {"none", "he", "rnn (ours)"}
    assert res["none"]["tracking"]["fixed"]["applicable"] is False  # no depth on a user's clip
    assert set(record["skipped_methods"]) == {"clean", "oracle-curve", "oracle-gain-gamma", "oracle-gamma"}  # no clean
    assert res["none"]["colmap"]["total"] == 10  # COLMAP still runs (intrinsics estimated)
    assert record["provenance"]["command"].startswith("colonlight evaluate ")


def test_synthetic_benchmark_is_rendered_once_and_evaluated(tmp_path: Path) -> None:
    out = tmp_path / "bench"
    args = ["evaluate", "--synthetic", "1", "--frames", "8", "--size", "64", "--methods", "none,rnn", "--no-colmap",
            "-o", str(out), "-q"]  # fmt: skip
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    marker = out / "clips" / "clip_00000" / "synth.json"
    stamp = marker.stat().st_mtime_ns
    meta = json.loads(marker.read_text())
    assert meta["seed"] == 800_000 and meta["config"]["split"] == "train"
    assert meta["config"]["close_occluder"] == "force"
    record = json.loads((out / "results.json").read_text())
    rows = {r["method"]: r for r in record["summary"]}
    assert rows["none"]["tracked"] == 1 and rows["rnn (ours)"]["clips"] == 1
    assert record["clips"][0]["correspondence"] == "depth+pose"
    again = runner.invoke(app, args)
    assert again.exit_code == 0, again.output
    assert marker.stat().st_mtime_ns == stamp  # complete clips are reused, not rendered again


def test_usage_errors_exit_2(tmp_path: Path) -> None:
    assert runner.invoke(app, ["evaluate", "-o", str(tmp_path)]).exit_code == 2  # nothing to evaluate
    bad = runner.invoke(app, ["evaluate", str(tmp_path), "--methods", "none,sharpen"])
    assert bad.exit_code == 2 and "sharpen" in bad.output


def test_rerun_reuses_tracking_and_colmap_and_adds_only_the_new_method(tmp_path: Path) -> None:
    """A re-run with one more method computes that method's scores only; the shared rows stay identical."""
    out = tmp_path / "bench"
    base = ["evaluate", "--synthetic", "1", "--frames", "10", "--size", "64", "-o", str(out), "-q"]
    first = runner.invoke(app, [*base, "--methods", "none,he"])
    assert first.exit_code == 0, first.output
    one = json.loads((out / "results.json").read_text())
    # 2 methods + 4 reference rows (clean and 3 oracles), each tracked in 2 settings + COLMAP once
    assert one["settings"]["cache"]["reused"] == 0 and one["settings"]["cache"]["computed"] == 18
    second = runner.invoke(app, [*base, "--methods", "none,he,clahe"])
    assert second.exit_code == 0, second.output
    two = json.loads((out / "results.json").read_text())
    assert two["settings"]["cache"] == {"folder": str(out / "cache"), "reused": 18, "computed": 3}
    for label in ("none", "he"):
        a, b = one["clips"][0]["results"][label], two["clips"][0]["results"][label]
        assert a["colmap"] == b["colmap"] and a["tracking"] == b["tracking"]
    assert "clahe" in two["clips"][0]["results"]
    # the key is the frames' content: other frames (another gamma) are scored afresh
    third = runner.invoke(app, [*base, "--methods", "gamma", "--no-colmap"])
    assert third.exit_code == 0, third.output
    assert json.loads((out / "results.json").read_text())["settings"]["cache"]["computed"] == 2  # fixed, affine


def test_brightness_both_fixed_and_bad(tmp_path: Path) -> None:
    """--brightness both (the default) puts both settings, the oracles and the gap closed in every output, the
    paper's (fixed) first; --brightness fixed tracks only in it, reusing the cached tracks; a bad value is a
    usage error."""
    out = tmp_path / "bench"
    base = ["evaluate", "--synthetic", "1", "--frames", "10", "--size", "64", "--methods", "none,rnn",
            "--no-colmap", "-o", str(out), "-q"]  # fmt: skip
    both = runner.invoke(app, [*base, "--brightness", "both"])
    assert both.exit_code == 0, both.output
    record = json.loads((out / "results.json").read_text())
    assert record["settings"]["brightness"] == ["fixed", "affine"]
    rows = {r["method"]: r for r in record["summary"]}
    assert list(rows) == ["clean", "oracle-curve", "oracle-gain-gamma", "oracle-gamma", "none", "rnn (ours)"]
    for m in ("fixed", "affine"):
        assert rows["none"][f"track_success_{m}"] in (0, 1) and 0 <= rows["none"][f"tracked_fraction_{m}"] <= 1
        assert f"gap_closed_tracked_{m}" in rows["rnn (ours)"] and f"rescue_rate_{m}" in rows["rnn (ours)"]
    assert set(record["failure_breakdown"]) == {"fixed", "affine"}
    md = (out / "table.md").read_text()
    assert md.index("fixed: success") < md.index("affine: success") and "gap closed" in md
    assert "fixed: success" in both.output.replace("\n", "") or "fixed" in both.output
    fixed = runner.invoke(app, [*base, "--brightness", "fixed"])
    assert fixed.exit_code == 0, fixed.output
    again = json.loads((out / "results.json").read_text())
    assert again["settings"]["brightness"] == ["fixed"] and again["settings"]["cache"]["computed"] == 0
    assert again["summary"][3]["track_success_affine"] is None
    bad = runner.invoke(app, [*base, "--brightness", "mode2"])
    assert bad.exit_code == 2 and "fixed, affine or both" in bad.output
