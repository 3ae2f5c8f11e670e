"""``colonlight enhance``: folders of videos (or frame folders) in, enhanced frames + per-frame gamma JSON out."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import typer

from colonlight import (
    ClipOptions,
    ManifestError,
    MethodSpec,
    OptionError,
    OutputError,
    default_workers,
    discover,
    network_threads,
    output_lock,
    read_camera,
    run_batch,
    tune_for_clips,
)
from colonlight.limits import (
    DEFAULT_FPS,
    DEFAULT_FRAME_FORMAT,
    DEFAULT_JPEG_QUALITY,
    MAX_JPEG_QUALITY,
    MIN_JPEG_QUALITY,
)

from . import options
from .display import BatchDisplay, console, error_line, problem_line, summary
from .failures import USAGE, ends_command
from .interrupts import INTERRUPTED, exit_code, signals_interrupt
from .loading import imports_frozen, load_method_or_exit


def enhance(
    ctx: typer.Context,
    inputs: list[Path] = typer.Argument(
        ..., help="Video files and/or folders (walked recursively; a folder of images is one clip)."
    ),
    output: Path = typer.Option(
        Path("colonlight-out"), "--output", "-o", envvar="COLONLIGHT_OUTPUT", help="Output folder."
    ),
    fps: float = typer.Option(
        DEFAULT_FPS,
        "--fps",
        envvar="COLONLIGHT_FPS",
        help="Extraction rate (FFmpeg fps-filter frame choice); 0 keeps every frame.",
    ),
    method: str = options.Method,
    # the method options: values checked by their declaration, read through options.method_kwargs
    weights: str | None = options.Weights,
    model_size: str | None = options.ModelSize,
    tone_match: str | None = options.ToneMatch,
    scene_cut: str | None = options.SceneCut,
    gamma: str | None = options.Gamma,
    device: str | None = options.Device,
    runtime: str | None = options.Runtime,
    content: str = options.Content,
    frames: bool = typer.Option(True, "--frames/--no-frames", help="Write enhanced frame images."),
    video: bool = typer.Option(
        False, "--video/--no-video", help="Also write enhanced.mp4 (H.264, yuv420p, faststart)."
    ),
    fmt: str = typer.Option(
        DEFAULT_FRAME_FORMAT, "--format", "-f", envvar="COLONLIGHT_FORMAT", help="Frame image format: png | jpg."
    ),
    quality: int = typer.Option(
        DEFAULT_JPEG_QUALITY, "--quality", min=MIN_JPEG_QUALITY, max=MAX_JPEG_QUALITY, help="JPEG quality."
    ),
    pattern: str | None = typer.Option(None, "--pattern", help="Glob on clip paths/names, e.g. '*.mp4' or 'site1/*'."),
    workers: int | None = typer.Option(
        None,
        "--workers",
        "-j",
        min=1,
        envvar="COLONLIGHT_WORKERS",
        help="Clips processed in parallel (default: one per two cores).",
    ),
    cluster: str | None = typer.Option(
        None, "--cluster", envvar="COLONLIGHT_CLUSTER", help="Dask scheduler address (tcp://HOST:8786) to run clips on."
    ),
    camera: Path | None = typer.Option(
        None,
        "--camera",
        help="DSO camera.txt or COLMAP cameras.txt to copy beside each clip's frames (checked against their size).",
    ),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="Redo clips whose outputs are complete (default: skip them)."
    ),
    max_pixels: int = options.MaxPixels,
    max_gap_frames: int = options.MaxGapFrames,
    quiet: bool = options.Quiet,
    debug: bool = options.Debug,
) -> None:
    # One line: `colonlight --help` shows the docstring's line breaks as they are.
    """Enhance every clip under INPUTS into OUTPUT/<clip>/ (frames/, gammas.json, enhanced.mp4, times.txt, rgb.txt) plus OUTPUT/manifest.json."""  # noqa: E501
    options.check_method(method)
    if fmt not in ("png", "jpg"):
        raise typer.BadParameter("choose png or jpg", param_hint="--format")
    options.check_fps(fps)
    with ends_command(USAGE, debug):
        cam = None if camera is None else read_camera(camera)
    try:
        clip_opts = ClipOptions(
            fps=fps or None,
            frames=frames,
            video=video,
            format=fmt,
            quality=quality,
            camera=None if cam is None else (cam.name, cam.text),
            max_pixels=max_pixels,
            max_gap_frames=max_gap_frames,
            content=content,
        )
    except OptionError as exc:
        raise typer.BadParameter(str(exc)) from exc
    spec = MethodSpec.of(method, **options.method_kwargs(ctx, method)[method])
    with signals_interrupt() as received:
        try:
            failed = _run(inputs, output, spec, clip_opts, pattern, workers, cluster, overwrite, quiet, debug)
        except KeyboardInterrupt:
            error_line(INTERRUPTED)  # the one wording every command ends an interrupt with
            raise typer.Exit(exit_code(received)) from None
    if failed:
        raise typer.Exit(1)


def _silence_dask_logs() -> None:
    """Keep Dask's own log lines off the console (``--debug`` shows them): a scheduler lost mid-batch made its
    client log an ERROR with a traceback, even after the batch had said so in one line per clip. For the rest of
    the process: the client's reconnect attempts log after the batch has returned."""
    try:
        import distributed  # noqa: F401 - importing it sets its loggers' levels, which this then overrides
    except ImportError:
        return  # the batch says in one line what to install
    for name in ("distributed", "distributed.client"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def _run(
    inputs: list[Path],
    output: Path,
    spec: MethodSpec,
    clip_opts: ClipOptions,
    pattern: str | None,
    workers: int | None,
    cluster: str | None,
    overwrite: bool,
    quiet: bool,
    debug: bool,
) -> bool:
    """The batch: load the model, hold the output folder, find the clips, run them. True if anything failed."""
    with imports_frozen():
        load_method_or_exit(spec, debug)  # load the model now: a bad checkpoint or absent device stops here, loudly
    tune_for_clips(network_threads(spec, 1))  # this process may run the clips: its torch threads and malloc, once
    if cluster and not debug:
        _silence_dask_logs()
    try:
        with output_lock(output):
            found = discover(inputs, output, pattern, exclude=[output])
            for problem in found.problems:
                problem_line(problem)
            if not found.jobs:
                error_line("no clips found in " + ", ".join(str(p) for p in inputs))
                return True
            n_workers = workers or default_workers(len(found.jobs))
            t0 = time.perf_counter()
            with BatchDisplay(len(found.jobs), quiet=quiet) as display:
                outcomes = run_batch(
                    found.jobs,
                    spec,
                    clip_opts,
                    output,
                    workers=n_workers,
                    overwrite=overwrite,
                    progress=None if quiet else display.event,
                    on_outcome=display.outcome,
                    cluster=cluster,
                    problems=found.problems,
                )
    except OutputError as exc:  # the output folder is a file, read-only, or held by another batch: a usage error
        error_line(str(exc))
        raise typer.Exit(2) from None
    except ManifestError as exc:
        error_line(str(exc))
        return True
    if debug:
        for o in outcomes:
            if o.detail:
                console.print(o.detail.encode("utf-8", "backslashreplace").decode("utf-8"), markup=False)
    summary(outcomes, time.perf_counter() - t0, str(output))
    return any(o.status == "failed" for o in outcomes) or any(p.failed for p in found.problems)


def register(app: typer.Typer) -> None:
    app.command("enhance")(enhance)
