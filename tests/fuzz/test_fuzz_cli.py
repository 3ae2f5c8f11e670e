"""Fuzz ``colonlight enhance`` with damaged real clips: no traceback, no hang, nothing half-written, bounded memory.

Each case is a folder holding one damaged clip (see :mod:`corrupt`) beside a sound one, enhanced with the cheap
``--method gamma`` in-process (typer's CliRunner: fast) and, for a few cases, by a real ``colonlight`` process
whose peak RSS is held to the bound that ``colonlight.pipeline.peak_rss_bound`` writes down. The damaged clip may
come out done (possibly flagged truncated) or failed with one line naming it; the sound one is always done; the
output folder passes :func:`checks.check_batch`. ``COLONLIGHT_FUZZ_EXAMPLES=500`` runs the long version.
"""

from __future__ import annotations

import shutil
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from colonlight_cli.main import app
from hypothesis import event, example, given
from hypothesis import strategies as st
from typer.testing import CliRunner

from colonlight.pipeline import peak_rss_bound

from ..commands import colonlight_command
from .checks import bounded, check_batch, run_measured
from .corrupt import FAMILIES, SEED_OUTPUT_FRAMES, Case, Cut, fuzz_settings

pytestmark = pytest.mark.timeout(900)

GAMMA = ("--method", "gamma", "-q")  # a real method that needs no model: these tests are about inputs and outputs
#: A pixel cap of 256x256 (the seeds are 32x32): a damaged header that claims more is refused before decoding,
#: so that the memory bound of a 256x256 clip holds whatever the damage.
MAX_PIXELS = 256 * 256
CASE_SECONDS = 60.0  # a case takes well under a second; past this it hangs


def enhance_args(inputs: list[Path], out: Path, video: bool) -> list[str]:
    return [
        "enhance",
        *map(str, inputs),
        "-o",
        str(out),
        *GAMMA,
        "-j",
        "1",
        "--max-pixels",
        str(MAX_PIXELS),
        "--video" if video else "--no-video",
    ]


def run_in_process(args: list[str]) -> tuple[int, str]:
    result = CliRunner().invoke(app, args)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        tb = "".join(traceback.format_exception(*result.exc_info)) if result.exc_info else repr(result.exception)
        raise AssertionError(f"colonlight enhance raised:\n{tb}\n{result.output}")
    return result.exit_code, result.output


def lay_out(case: Case, seeds: dict[str, Path], d: Path) -> tuple[Path, dict[str, Path]]:
    """``d/in/`` with the damaged clip and a sound one; returns the folder and the clips by output name."""
    inputs = d / "in"
    bad = case.write(seeds, inputs)
    good = inputs / "good.mp4"
    shutil.copyfile(seeds["mp4"], good)
    return inputs, {"clip": bad, "good": good}


def check_case(case: Case, video: bool, seeds: dict[str, Path], case_dir: Callable[[], Iterator[Path]]) -> None:
    with case_dir() as d:
        inputs, clips = lay_out(case, seeds, d)
        out = d / "out"
        code, console = bounded(
            lambda: run_in_process(enhance_args([inputs], out, video)), CASE_SECONDS, f"colonlight enhance of {case}"
        )
        entries = check_batch(out, console, code, clips, video, must_succeed={"good"})
        assert entries["good"]["frames"] == SEED_OUTPUT_FRAMES
        bad = entries["clip"]
        event("done, truncated" if bad.get("truncated") else bad["status"])
        if bad["status"] == "failed" and (out / "clip" / "frames").exists():
            event("failed, whole frames left without a gammas.json")


@fuzz_settings(12)
@given(case=FAMILIES["flips"], video=st.booleans())
def test_flipped_bytes(case: Case, video: bool, seeds: dict[str, Path], case_dir: Callable[[], Iterator[Path]]) -> None:
    check_case(case, video, seeds, case_dir)


@fuzz_settings(12)
@given(case=FAMILIES["cuts"], video=st.booleans())
@example(case=Case("avi", (Cut(0),)), video=False)  # found: a 0-byte clip failed but left an empty OUT/clip/
def test_truncated_at_any_offset(
    case: Case, video: bool, seeds: dict[str, Path], case_dir: Callable[[], Iterator[Path]]
) -> None:
    check_case(case, video, seeds, case_dir)


@fuzz_settings(12)
@given(case=FAMILIES["chunks"], video=st.booleans())
def test_duplicated_and_dropped_chunks(
    case: Case, video: bool, seeds: dict[str, Path], case_dir: Callable[[], Iterator[Path]]
) -> None:
    check_case(case, video, seeds, case_dir)


@fuzz_settings(12)
@given(case=FAMILIES["packets"], video=st.booleans())
def test_duplicated_and_dropped_packets(
    case: Case, video: bool, seeds: dict[str, Path], case_dir: Callable[[], Iterator[Path]]
) -> None:
    check_case(case, video, seeds, case_dir)


@fuzz_settings(12)
@given(case=FAMILIES["foreign"], video=st.booleans())
def test_foreign_headers_and_wrong_suffixes(
    case: Case, video: bool, seeds: dict[str, Path], case_dir: Callable[[], Iterator[Path]]
) -> None:
    check_case(case, video, seeds, case_dir)


@fuzz_settings(12)
@given(case=FAMILIES["mixed"], video=st.booleans())
def test_mixed_damage(case: Case, video: bool, seeds: dict[str, Path], case_dir: Callable[[], Iterator[Path]]) -> None:
    check_case(case, video, seeds, case_dir)


@fuzz_settings(3)
@given(case=FAMILIES["mixed"])
def test_real_process_within_the_memory_bound(
    case: Case, seeds: dict[str, Path], case_dir: Callable[[], Iterator[Path]]
) -> None:
    """A real ``colonlight enhance`` process (with --video): the same properties, its own time bound, and a peak
    RSS within the written bound for the largest frame the pixel cap admits."""
    with case_dir() as d:
        inputs, clips = lay_out(case, seeds, d)
        out = d / "out"
        code, stderr, peak = run_measured(colonlight_command(*enhance_args([inputs], out, True)), CASE_SECONDS)
        check_batch(out, stderr, code, clips, True, must_succeed={"good"})
        bound = peak_rss_bound(256, 256, workers=1, video=True)
        assert peak <= bound, f"peak RSS {peak / 2**20:.0f} MiB > bound {bound / 2**20:.0f} MiB for {case}"
