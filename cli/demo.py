"""``colonlight demo``: the main job end to end on an embedded default, with no data of the user's."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from colonlight import (
    GAMMAS_FILE,
    MANIFEST_FILE,
    VIDEO_FILE,
    ClipOptions,
    MethodSpec,
    discover_clips,
    network_threads,
    run_batch,
    tune_for_clips,
)
from colonlight.limits import DEFAULT_FPS

from .display import BatchDisplay, console, error_line, printable
from .failures import USAGE, ends_command
from .interrupts import interruptible

DEMO_SEED = 20210628  # the clip is rendered from "heldout" settings, never used to train the default model
DEMO_FPS = 30.0  # the rate the clip is rendered at, as a recorder's; enhance takes DEFAULT_FPS of it


def demo(
    output: Path = typer.Option(Path("colonlight-demo"), "--output", "-o", help="Where the demo clip and results go."),
    frames: int = typer.Option(
        90,
        "--frames",
        min=10,
        help=f"Length of the synthetic clip in frames, rendered at {DEMO_FPS:g} fps (enhance keeps about "
        f"{DEFAULT_FPS:g} of every {DEMO_FPS:g}: 90 frames, 3 s, give 54).",
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No live display."),
) -> None:
    """Render a synthetic colonoscopy clip, enhance it with the default model, and say where everything is."""
    import numpy as np

    from colonlight import OutputError, prepare_output
    from colonlight.synth import SYNTH_VIDEO, SynthConfig, clip_complete, write_clip

    with ends_command(USAGE, kinds=(OutputError,)):  # an output that is a file (or under one) was a traceback
        prepare_output(output)
    clip_dir = output / "input"
    cfg = SynthConfig.sample(
        np.random.default_rng(DEMO_SEED),
        split="heldout",
        width=480,
        height=384,
        n_frames=frames,
        fps=DEMO_FPS,
        undisturbed_seeds=True,
    )
    video_path = clip_dir / SYNTH_VIDEO
    # The clip is kept only if it is the one asked for: a rerun with another --frames reused the first run's
    # clip and its enhanced result, and reported them as if they were of the length asked for.
    rendered = not clip_complete(clip_dir, cfg, DEMO_SEED, video=True)
    if rendered:
        console.print(
            f"rendering a synthetic clip ({frames} frames at {DEMO_FPS:g} fps) into {printable(str(clip_dir))} ...",
            soft_wrap=True,
        )
        write_clip(clip_dir, cfg, seed=DEMO_SEED, video=True, frames=False)
    enhanced = output / "enhanced"
    jobs = discover_clips([video_path], enhanced)
    spec = MethodSpec.of("rnn")
    tune_for_clips(network_threads(spec, 1), load_torch=True)  # this process runs the clip, as enhance's does
    with BatchDisplay(len(jobs), quiet=quiet) as display:
        outcomes = run_batch(
            jobs,
            spec,
            ClipOptions(fps=DEFAULT_FPS, video=True),
            enhanced,
            overwrite=rendered,  # a new clip: the result of the one it replaced is not its result
            progress=None if quiet else display.event,
            on_outcome=display.outcome,
        )
    if outcomes[0].status != "done":
        error_line(outcomes[0].error or "demo failed")
        raise typer.Exit(1)
    result = jobs[0].out_dir
    gammas = [f["gamma"] for f in json.loads((result / GAMMAS_FILE).read_text())["frames"]]
    console.print(
        f"\n[bold]colonlight demo done[/]: {len(gammas)} frames extracted at {DEFAULT_FPS:g} fps from a "
        f"{DEMO_FPS:g} fps clip, "
        f"gamma {min(gammas):.2f}..{max(gammas):.2f}\n"
        f"  input clip      {printable(str(video_path))}\n"
        f"  enhanced frames {printable(str(result / 'frames'))}/\n"
        f"  per-frame gamma {printable(str(result / GAMMAS_FILE))}\n"
        f"  enhanced video  {printable(str(result / VIDEO_FILE))}\n"
        f"  manifest        {printable(str(enhanced / MANIFEST_FILE))}",
        soft_wrap=True,
    )


def register(app: typer.Typer) -> None:
    app.command("demo")(interruptible(demo))  # SIGTERM as Ctrl-C: temporaries removed, exit 143
