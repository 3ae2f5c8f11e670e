"""``colonlight evaluate``: run methods on clips (a user's, or the held-out synthetic benchmark) and report."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from colonlight import ColonlightError, parse_content
from colonlight.limits import DEFAULT_FPS

from . import options
from .display import console, error_line, printable
from .failures import FAILED, USAGE, ends_command
from .interrupts import interruptible

TRAINING_SEEDS = range(1000, 1100)  # colonlight train's synthetic clips
GATE_SEEDS = range(700_000, 700_024)  # benchmarks/quality_gate.py


def _method_names(text: str) -> list[str]:
    from colonlight import available_methods

    names = [n.strip() for n in text.split(",") if n.strip()]
    known = available_methods()
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise typer.BadParameter(
            f"unknown method(s) {', '.join(bad) or '(none given)'}; available: {', '.join(known)}",
            param_hint="--methods",
        )
    return list(dict.fromkeys(names))


class _Display:
    """Progress over clips (and the methods of the running clip); one line per finished or failed clip."""

    def __init__(self, n_clips: int, n_methods: int, quiet: bool) -> None:
        self.quiet = quiet
        self.n_methods = n_methods
        self.started = time.perf_counter()
        self.clip_started = self.started
        self.progress: Progress | None = None
        if not quiet:
            self.progress = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=console,
            )
            self.clips = self.progress.add_task("[bold]clips", total=n_clips)
            self.methods = self.progress.add_task("  methods", total=n_methods, visible=False)

    def __enter__(self) -> _Display:  # noqa: PYI034 - a private class, never subclassed
        if self.progress:
            self.progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.progress:
            self.progress.stop()

    def line(self, text: str) -> None:
        (self.progress.console if self.progress else console).print(text, soft_wrap=True)

    def event(self, event: str, data: dict[str, Any]) -> None:
        if event == "skipped":
            self.n_methods -= 1
            self.line(f"[yellow]skipped[/] method {data['method']}: {printable(str(data['error']))}")
        elif event == "clip":
            self.clip_started = time.perf_counter()
            if self.progress:
                self.progress.reset(self.methods, total=self.n_methods, visible=True)
                self.progress.update(self.methods, description=f"  {printable(str(data['clip']))}")
        elif event == "method":
            if data.get("error"):
                what = f"{data['clip']} / {data['method']}: {data['error']}"
                self.line(f"[red]failed[/]  {printable(what)}")
            if self.progress:
                self.progress.advance(self.methods)
                self.progress.update(
                    self.methods, description=f"  {printable(str(data['clip']))}: {data['method']} done"
                )
        elif event == "failed":
            self.line(f"[red]failed[/]  {printable(str(data['error']))}")
            if self.progress:
                self.progress.advance(self.clips)
        elif event == "done":
            seconds = time.perf_counter() - self.clip_started
            self.line(f"[green]done[/]    {printable(str(data['clip']))} in {seconds:.1f} s")
            if self.progress:
                self.progress.advance(self.clips)
                self.progress.update(self.methods, visible=False)


def _summary_table(rows: list[dict[str, Any]], modes: tuple[str, ...]) -> Table:
    """Per method: flicker, consistency, exposure, then per brightness setting (fixed, the paper's, first)
    tracker success, tracked fraction and the share of the input -> oracle-curve gap closed, then COLMAP."""
    from colonlight.evaluation import fmt, fmt_pair, success_cell

    table = Table(title="colonlight evaluate", header_style="bold")
    columns = ["method", "clips", "flicker in -> out", "MC-SSIM out", "dark/bright % out"]
    for m in modes:
        columns += [f"{m}: success", f"{m}: tracked", f"{m}: gap closed"]
    columns += ["COLMAP reg.", "ATE rmse mm", "ms/frame"]
    for col in columns:
        table.add_column(col, justify="left" if col == "method" else "right")
    for r in rows:
        cells = [
            r["method"],
            str(r["clips"]),
            fmt_pair(r["flicker_in"], r["flicker_out"]),
            fmt(r["ssim_out"], ".3f"),
            f"{fmt(r['dark_out'], '.1f', 100)} / {fmt(r['bright_out'], '.2f', 100)}",
        ]
        for m in modes:
            cells += [
                success_cell(r, m),
                fmt(r[f"tracked_fraction_{m}"], ".3f"),
                f"{fmt(r[f'gap_closed_success_{m}'], '.0%')} / {fmt(r[f'gap_closed_tracked_{m}'], '.0%')}",
            ]
        cells += [
            fmt(r["registered"], ".0%") if r["colmap_clips"] else "n/a",
            fmt(r["ate_rmse_m"], ".2f", 1000),
            fmt(r["ms_per_frame"], ".1f"),
        ]
        table.add_row(*cells)
    return table


def evaluate(
    ctx: typer.Context,
    inputs: Annotated[
        list[Path] | None,
        typer.Argument(
            help="Video files and/or folders (walked recursively; synthetic clip folders are found by synth.json)."
        ),
    ] = None,
    output: Annotated[Path, typer.Option("--output", "-o", help="Report folder.")] = Path("colonlight-eval"),
    methods: Annotated[
        str,
        typer.Option(
            "--methods",
            "-m",
            help="Comma-separated methods; rnn is ours (default model). Methods without weights are skipped.",
        ),
    ] = "none,he,clahe,deflicker,zerodce,zerodce++,rnn",
    authors_checkpoint: Annotated[
        Path | None,
        typer.Option("--authors-checkpoint", help="The authors' released .pth: adds the method 'rnn (authors)'."),
    ] = None,
    synthetic: Annotated[
        int,
        typer.Option(
            "--synthetic",
            min=0,
            help="Also evaluate N synthetic clips with unseen seeds, rendered into OUTPUT/clips/ (reused if complete).",
        ),
    ] = 0,
    seed0: Annotated[
        int, typer.Option("--seed0", min=0, help="Seed of the first synthetic clip (clip i: seed0 + i).")
    ] = 800_000,  # colonlight.evaluation.clips.BENCHMARK_SEED0 (not imported: keeps `colonlight --help` light)
    frames: Annotated[int, typer.Option("--frames", min=2, help="Frames per synthetic clip.")] = 72,
    family: Annotated[
        str,
        typer.Option(
            "--family",
            help="Synthetic settings: train (the generator's training ranges, unseen seeds; trackable motion) "
            f"or heldout (knobs pushed outside them, often faster than a tracker can follow at {DEFAULT_FPS:g} fps).",
        ),
    ] = "train",
    size: Annotated[int, typer.Option("--size", min=32, help="Side of the synthetic frames in pixels.")] = 256,
    colmap: Annotated[
        bool, typer.Option("--colmap/--no-colmap", help="Run COLMAP (pycolmap) on every method's frames.")
    ] = True,
    tracker: Annotated[
        bool,
        typer.Option("--tracker/--no-tracker", help="Run the photometric tracker (clips with known depth)."),
    ] = True,
    brightness: Annotated[
        str,
        typer.Option(
            "--brightness",
            help="Tracker's per-frame affine brightness: fixed (a = b = 0, the paper's RNNSLAM/DSO mode=2), "
            "affine (fitted, DSO mode=1) or both.",
        ),
    ] = "both",
    oracles: Annotated[
        bool,
        typer.Option(
            "--oracles/--no-oracles",
            help="On clips with clean frames, add the rows clean, oracle-curve, oracle-gain-gamma and oracle-gamma "
            "(ceilings for a global per-frame correction) and the breakdown of the input's failures.",
        ),
    ] = True,
    content: str = options.Content,
    fps: Annotated[
        float, typer.Option("--fps", help="Extraction rate of videos (FFmpeg fps-filter choice); 0 keeps all.")
    ] = DEFAULT_FPS,
    max_size: Annotated[
        int,
        typer.Option("--max-size", min=0, help="Working size: long side shrunk to at most this (0: full size)."),
    ] = 256,
    max_frames: Annotated[
        int, typer.Option("--max-frames", min=0, help="Evaluate at most this many frames per clip (0: all).")
    ] = 0,
    # the method options, as enhance takes them: each goes to the methods in --methods that take it
    weights: str | None = options.Weights,
    model_size: str | None = options.ModelSize,
    tone_match: str | None = options.ToneMatch,
    scene_cut: str | None = options.SceneCut,
    gamma: str | None = options.Gamma,
    device: str | None = options.Device,
    runtime: str | None = options.Runtime,
    threads: Annotated[
        int,
        typer.Option("--threads", min=1, help="Torch/OpenCV threads while evaluating (cost measured alike)."),
    ] = 1,
    workers: Annotated[int, typer.Option("--workers", "-j", min=1, help="Processes rendering synthetic clips.")] = 1,
    cache: Annotated[
        bool,
        typer.Option(
            "--cache/--no-cache",
            help="Keep tracking/COLMAP results in OUTPUT/cache and reuse them for byte-identical frames "
            "(re-running after adding a method computes only the new one).",
        ),
    ] = True,
    quiet: bool = options.Quiet,
    debug: bool = options.Debug,
) -> None:
    """Measure lighting consistency, exposure, tracking, COLMAP and cost of each method; write OUTPUT/report.html,
    results.json, table.md, table.csv and clips.csv."""  # fmt: skip
    from colonlight.evaluation import require_extras

    names = _method_names(methods)
    options.check_fps(fps)
    if max_frames == 1:  # every clip failed with "only 1 frame(s); at least 2 are needed"
        raise typer.BadParameter(
            "1 frame has no frame pair to compare: give 0 (all) or 2 or more", param_hint="--max-frames"
        )
    from colonlight.synth import SPLITS, parse_split

    try:
        split = parse_split(family)
    except ValueError:
        raise typer.BadParameter(f"choose {' or '.join(SPLITS)}", param_hint="--family") from None
    if brightness not in ("fixed", "affine", "both"):
        raise typer.BadParameter("choose fixed, affine or both", param_hint="--brightness")
    try:
        content = parse_content(content)
    except ColonlightError as exc:
        raise typer.BadParameter(str(exc), param_hint="--content") from None
    with ends_command(USAGE, debug):
        require_extras(colmap)
    # only now: the evaluation's own modules import the extra's packages
    from colonlight.evaluation import (
        evaluate_clips,
        find_clips,
        make_benchmark,
        method_list,
        summarize,
        unique_clips,
        write_report,
    )

    if not inputs and not synthetic:
        raise typer.BadParameter("give clips to evaluate, or --synthetic N", param_hint="INPUTS")
    from colonlight import OutputError, prepare_output

    # before any work: an output that is a file or cannot be written is one line, not a traceback at the end
    with ends_command(USAGE, debug, kinds=(OutputError,)):
        prepare_output(output)
    rows = [*names, *(["rnn"] if authors_checkpoint is not None and "rnn" not in names else [])]
    specs = method_list(names, authors_checkpoint, chosen=options.method_kwargs(ctx, *rows))
    if authors_checkpoint is not None and not authors_checkpoint.is_file():
        console.print(
            f"[yellow]note[/]: the authors' checkpoint {printable(str(authors_checkpoint))} is not a file",
            soft_wrap=True,
        )

    refs = find_clips(inputs or [])
    if synthetic:
        overlap = [r for r in (TRAINING_SEEDS, GATE_SEEDS) if seed0 < r.stop and r.start < seed0 + synthetic]
        if overlap:
            console.print(
                f"[yellow]warning[/]: seeds {seed0}..{seed0 + synthetic - 1} overlap seeds used for "
                "training or the quality gate; the benchmark should use unseen seeds (e.g. 800000+)"
            )
        clip_dir = output / "clips"
        done = [0]

        def rendered(folder: Path, new: bool) -> None:
            done[0] += 1
            if new:
                console.print(f"[dim]rendered[/] {printable(str(folder))} ({done[0]}/{synthetic})", soft_wrap=True)

        if not quiet:
            console.print(
                f"synthetic benchmark: {synthetic} clips ({family} settings) x {frames} frames ({size}x{size}) "
                f"in {printable(str(clip_dir))}",
                soft_wrap=True,
            )
        refs += make_benchmark(
            clip_dir,
            synthetic,
            seed0,
            frames,
            size,
            workers=workers,
            on_clip=rendered,
            family=split,
        )
        refs = unique_clips(refs)  # a benchmark rendered into an input folder (-o INPUT) was found there too
    if not refs:
        error_line("no clips found in " + ", ".join(str(p) for p in inputs or []))
        raise typer.Exit(1)

    with _Display(len(refs), len(specs) + (3 if oracles else 0), quiet) as display, ends_command(FAILED, debug):
        result = evaluate_clips(
            refs, specs, colmap=colmap, tracker=tracker, max_size=max_size or None, fps=fps,
            max_frames=max_frames or None, threads=threads, progress=display.event,
            brightness=brightness, oracles=oracles, content=content,
            cache_dir=output / "cache" if cache else None,
        )  # fmt: skip
    if not result.methods:
        error_line("no method could be run: " + "; ".join(f"{k}: {v}" for k, v in result.skipped_methods.items()))
        raise typer.Exit(1)
    if debug:
        for c in result.clips:
            for r in c.results.values():
                if r.detail:
                    console.print(r.detail, markup=False)
    paths = write_report(result, output, command=options.invocation(ctx))
    modes = tuple(result.settings.get("brightness") or ())
    console.print(_summary_table(summarize(result), modes))
    if modes and oracles:
        console.print(
            "tracking: brightness fixed first (the paper's setting: RNNSLAM runs DSO with mode=2, brightness not "
            "optimised); gap closed = share of the input -> oracle-curve gap (success / tracked)"
        )
    shown = {key: printable(str(path)) for key, path in paths.items()}  # an OUTPUT with [/] in it is no markup
    console.print(f"report: {shown['html']}", soft_wrap=True)
    console.print(f"tables: {shown['markdown']}, {shown['csv']}; everything: {shown['json']}", soft_wrap=True)
    if result.failed:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    app.command("evaluate")(interruptible(evaluate))  # SIGTERM as Ctrl-C: temporaries removed, exit 143
