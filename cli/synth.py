"""``colonlight synth``: synthetic colonoscopy clips with ground truth (poses, depth, clean frames, lighting)."""

from __future__ import annotations

from pathlib import Path

import typer

from colonlight.limits import DEFAULT_FPS, MAX_FPS

from .display import console, error_line, printable
from .interrupts import interruptible
from .options import MAX_RENDER_SIDE, clip_mix


def synth(
    output: Path = typer.Argument(..., help="Folder to write clips into (one sub-folder per clip)."),
    clips: int = typer.Option(1, "--clips", "-n", min=1, help="Number of clips."),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the first clip; clip i uses seed + i."),
    frames: int = typer.Option(90, "--frames", min=2, help="Frames per clip."),
    width: int = typer.Option(384, "--width", min=32, max=MAX_RENDER_SIDE),
    height: int = typer.Option(288, "--height", min=32, max=MAX_RENDER_SIDE),
    fps: float = typer.Option(
        DEFAULT_FPS, "--fps", min=1.0, max=MAX_FPS, help="Frame rate of the clip (and its timestamps)."
    ),
    split: str = typer.Option(
        "train", "--split", help="Parameter family: train | heldout (ranges never used in training)."
    ),
    video: bool = typer.Option(True, "--video/--no-video", help="Write clip.mp4 (H.264)."),
    workers: int = typer.Option(2, "--workers", "-j", min=1),
    border: str = typer.Option(
        "none", "--border", help="Draw a scope's black border around the field of view: none | round | octagon."
    ),
    fov: float = typer.Option(
        0.96, "--fov", min=0.3, max=1.0, help="Field of view height as a share of the frame height (with --border)."
    ),
    text: bool = typer.Option(
        False, "--text/--no-text", help="Draw fixed on-screen text (patient fields, time, scope settings)."
    ),
    steady: float = clip_mix("steady", "--steady", 0.0),
    occluders: float = clip_mix("occluders", "--occluders", 0.0),
    clean_seeds: float = clip_mix("clean-seeds", "--clean-seeds", 0.0),
) -> None:
    """Render synthetic colonoscopy clips: frames/, clean/, depth/, poses.txt (TUM), intrinsics.json, lighting.json."""
    from colonlight import parent_problem
    from colonlight.synth import BORDERS, SPLITS, OverlaySpec, make_dataset, parse_split

    try:
        family = parse_split(split)
    except ValueError:
        raise typer.BadParameter(f"choose {' or '.join(SPLITS)}", param_hint="--split") from None
    if border not in BORDERS:
        raise typer.BadParameter(f"choose one of {', '.join(BORDERS)}", param_hint="--border")
    overlay = OverlaySpec(border=border, fov=fov, text=text)  # type: ignore[arg-type]
    blocked = parent_problem(output / "clip")  # the folder, or a parent, is a file: said for what it is, first
    if blocked:
        error_line(f"{output}: cannot write the clips: {blocked}")  # error_line escapes
        raise typer.Exit(1)
    try:
        paths = make_dataset(
            output,
            clips,
            seed=seed,
            split=family,
            width=width,
            height=height,
            n_frames=frames,
            fps=fps,
            workers=workers,
            video=video,
            steady_fraction=steady,
            occluder_fraction=occluders,
            clean_seeds_fraction=clean_seeds,
            overlay=overlay if overlay.active else None,
        )
    except OSError as exc:  # the output is a file, read-only, full: one line naming the path, not a traceback
        error_line(f"{exc.filename or output}: cannot write the clips: {exc.strerror or exc}")
        raise typer.Exit(1) from None
    for p in paths:
        console.print(f"wrote {printable(str(p))}", soft_wrap=True)


def register(app: typer.Typer) -> None:
    app.command("synth")(interruptible(synth))  # SIGTERM as Ctrl-C: temporaries removed, exit 143
