"""``colonlight train``: the paper's unsupervised objective on your clips, or on synthetic ones."""

from __future__ import annotations

import itertools
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from colonlight.limits import DEFAULT_FPS, DEFAULT_MODEL_SIZE, MAX_LEARNING_RATE, MAX_MODEL_SIZE, MAX_TRAIN_SEED

from .display import console, error_line, printable
from .failures import FAILED, ends_command
from .interrupts import interruptible
from .options import MAX_RENDER_SIDE, check_fps, clip_mix, invocation

if TYPE_CHECKING:
    from collections.abc import Iterator

    import numpy as np

    from colonlight import EpochRecord, TrainConfig


def _synthetic_clips(
    run_dir: Path,
    n: int,
    seed: int,
    frames: int,
    split: str,
    render: int,
    steady: float,
    occluders: float,
    clean_seeds: float,
) -> list[Path]:
    """Render (or reuse) synthetic clips from the generator's training family; returns their frame folders."""
    from colonlight.synth import SYNTH_FRAMES, make_dataset

    dirs = make_dataset(
        run_dir / "data" / split,
        n,
        seed=seed,
        split="train",
        width=render,
        height=render,
        n_frames=frames,
        fps=DEFAULT_FPS,
        workers=2,
        video=False,
        steady_fraction=steady,
        occluder_fraction=occluders,
        clean_seeds_fraction=clean_seeds,
    )
    return [d / SYNTH_FRAMES for d in dirs]


def _clips(paths: list[Path]) -> list[Path]:
    """The clips under ``paths``; a synthetic clip folder trains on its lossless ``frames/`` (frame for frame
    beside ``clean/``, which the restoring objectives need), not on its H.264 ``clip.mp4``."""
    from colonlight import discover_clips, synthetic_folder_of
    from colonlight.synth import SYNTH_FRAMES

    clips = []
    for job in discover_clips(paths, Path(".")):
        folder = synthetic_folder_of(job.source)
        frames = folder / SYNTH_FRAMES if folder is not None else None
        clips.append(frames if frames is not None and frames.is_dir() else job.source)
    return clips


def _init_design(init: str | None, head: str | None) -> tuple[str, str]:
    """The head and input a run keeps when ``--head`` / ``--inputs`` are not given: the starting checkpoint's
    (fine-tuning the shipped curve model keeps its head and output layer), else the paper's (one gamma,
    from RGB). Asked for the paper's head (``head``), a run from the shipped model (input ``delta``) reads RGB,
    the paper's input (``GammaNet.inputs_for_head``)."""
    if not init:
        return "gamma", "rgb"
    from colonlight import CheckpointError, load_weights

    try:
        net = load_weights(init).net
    except CheckpointError as exc:
        raise typer.BadParameter(str(exc), param_hint="--init") from None
    return net.head, net.inputs_for_head(head or net.head)


def _rnn_config(frame_steps: str, **options: Any) -> TrainConfig:
    """The run's TrainConfig from the command's options, or a usage error naming the option that no run can use."""
    from colonlight import OptionError, TrainConfig, parse_frame_steps

    try:
        return TrainConfig(frame_steps=parse_frame_steps(frame_steps), **options)
    except OptionError as exc:
        raise typer.BadParameter(str(exc)) from None


def train_cmd(
    ctx: typer.Context,
    data: list[Path] | None = typer.Argument(None, help="Clips: videos and/or frame folders (walked recursively)."),
    output: Path = typer.Option(
        Path("colonlight-train"), "--output", "-o", help="Run folder: checkpoints/, the weights and card."
    ),
    val: list[Path] | None = typer.Option(
        None,
        "--val",
        help="Validation clip; repeat the option for more (--val a --val b; in --val a b, b is a training "
        "clip). Default: the last clip of DATA.",
    ),
    synthetic: int = typer.Option(0, "--synthetic", min=0, help="Also render this many synthetic training clips."),
    synthetic_seed: int = typer.Option(1000, "--synthetic-seed", min=0, help="Seed of the first synthetic clip."),
    synthetic_frames: int = typer.Option(100, "--synthetic-frames", min=12),
    synthetic_val: int = typer.Option(
        2, "--synthetic-val", min=0, help="Synthetic validation clips (seeds after the training ones)."
    ),
    synthetic_size: int = typer.Option(
        128,
        "--synthetic-size",
        min=32,
        max=MAX_RENDER_SIDE,
        help="Render size of synthetic clips (then resized to --size).",
    ),
    synthetic_steady: float = clip_mix("steady", "--synthetic-steady", 0.25),
    synthetic_occluders: float = clip_mix("occluders", "--synthetic-occluders", 0.0),
    synthetic_clean_seeds: float = clip_mix("clean-seeds", "--synthetic-clean-seeds", 0.0),
    head: str | None = typer.Option(
        None,
        "--head",
        help="gamma (the paper's: one gamma per frame) | gain-gamma (a gain and a gamma per frame) | "
        "curve (a monotone tone curve per frame). Default: the --init checkpoint's head, else gamma.",
        show_default=False,
    ),
    objective: str = typer.Option(
        "paper",
        "--objective",
        help="paper (unsupervised, the paper's loss) | restore (to the clean frames of synthetic clips) | "
        "relative (to the clean frames as each window's first frame shows them: steady video is left alone) | "
        "hybrid (restore and the paper's loss).",
    ),
    consistency: float = typer.Option(
        0.5, "--consistency", min=0.0, help="Weight of the paper's loss in --objective hybrid."
    ),
    temporal: float = typer.Option(
        0.0,
        "--temporal",
        min=0.0,
        help="Weight of the restoration error's frame-to-frame change (--objective restore|relative|hybrid): the "
        "output flickers no more than the clean frames.",
    ),
    exposure_jitter: float = typer.Option(
        0.0,
        "--exposure-jitter",
        min=0.0,
        help="With --objective relative: pass each window, frames and targets alike, through a random exposure "
        "change (|log gain| up to this, |log gamma| up to half), so that absolute brightness stops being a cue "
        "for the correction. An experiment: it did not keep steady clips from being darkened (README).",
    ),
    frame_steps: str = typer.Option(
        "1",
        "--frame-steps",
        help="Comma-separated frame steps k: each clip also gives windows of every k-th frame (1,2: the camera "
        "and its lighting twice as fast as recorded, without rendering more). An experiment (README, session 27).",
    ),
    steady_weight: float = typer.Option(
        1.0,
        "--steady-weight",
        help="With --objective restore|relative|hybrid: weight of the windows whose recorded frames are exactly "
        "their clean frames (steady lighting, where the right output is the input) against the others' 1. "
        "An experiment (README, session 30).",
    ),
    darken_weight: float = typer.Option(
        1.0,
        "--darken-weight",
        help="With --objective restore|relative|hybrid: a sample corrected darker than its clean target costs "
        "this many times its error (above 1: where a scene's own brightening and the camera's look alike, lean "
        "towards leaving it). An experiment (README, session 36).",
    ),
    darken_level: float = typer.Option(
        0.0,
        "--darken-level",
        help="With --objective restore|relative|hybrid: add this many times the mean amount by which a frame's "
        "mean level falls below its target's (the level alone leans towards leaving a brightening; the tones "
        "stay a symmetric fit). An experiment (README, session 36).",
    ),
    inputs: str | None = typer.Option(
        None,
        "--inputs",
        help="rgb (the paper's) | rgb-log (the frame and its log intensity, in which a gain change is the same "
        "shift everywhere) | rgb-prev (the frame and the frame under the last frame's correction; gain-gamma and "
        "curve heads) | delta (the frame under the last correction and its difference from the last output; the "
        "head changes the last correction; gain-gamma and curve heads) | delta-rank (delta and how far the pixels' "
        "brightness order changed since the last frame: a scene change, not a lighting one; README, session 28). "
        "Default: the --init checkpoint's, else "
        "rgb; an rgb checkpoint starts the others with zero weights on the extra channels.",
        show_default=False,
    ),
    method: str = typer.Option("rnn", "--method", help="rnn (the paper's model) | zerodce | zerodce++ (baselines)."),
    size: int = typer.Option(
        DEFAULT_MODEL_SIZE,
        "--size",
        min=16,
        max=MAX_MODEL_SIZE,
        help="Training input size; the card records it, and the model runs at it unless --model-size is given.",
    ),
    epochs: int = typer.Option(10, "--epochs", min=1),
    batch: int = typer.Option(4, "--batch", min=1),
    lr: float = typer.Option(5e-5, "--lr"),
    seq_len: int = typer.Option(10, "--seq-len", min=3),
    stride: int = typer.Option(5, "--stride", min=1),
    seed: int = typer.Option(0, "--seed", min=0, max=MAX_TRAIN_SEED),
    anchor: float = typer.Option(
        0.0,
        "--anchor",
        min=0.0,
        help="Weight of the brightness anchor added to the paper's loss (0: the paper's objective exactly).",
    ),
    init: str | None = typer.Option(
        None, "--init", help="Start from a checkpoint (ours or the authors' .pth), or 'default'."
    ),
    name: str = typer.Option("colonlight-rnn", "--name", help="Name of the weights file and card."),
    resume: bool = typer.Option(True, "--resume/--no-resume", help="Continue from the last epoch saved in OUTPUT."),
    fps: float = typer.Option(DEFAULT_FPS, "--fps", help="Extraction rate for video clips (0: every frame)."),
    export_epoch: int | None = typer.Option(
        None,
        "--export-epoch",
        min=1,
        help="Train nothing: write the weights and card of epoch N of the run in OUTPUT (from the state saved "
        "after it) as OUTPUT/NAME-epochNNN.safetensors, for a model chosen on validation clips before the last "
        "epoch. Every other option is ignored: the card is the run's own.",
        show_default=False,
    ),
) -> None:
    """Train a model; writes OUTPUT/NAME.safetensors and its model card OUTPUT/NAME.json."""
    if export_epoch is not None:
        _export_epoch(output, export_epoch)
        return
    _check_numbers(fps, lr, consistency=consistency, temporal=temporal, exposure_jitter=exposure_jitter, anchor=anchor)
    _check_name(name)
    _check_output(output)
    if method not in ("rnn", "zerodce", "zerodce++"):
        raise typer.BadParameter("choose rnn, zerodce or zerodce++", param_hint="--method")
    if method == "rnn" and init == "default":
        from colonlight import DEFAULT_WEIGHTS

        init = str(DEFAULT_WEIGHTS)
    if method == "rnn":  # --init is read now, even with --head and --inputs given: bad, it fails before any rendering
        init_head, init_inputs = _init_design(init, head)
        head, inputs = head or init_head, inputs or init_inputs
    # Every usage error comes before the lock: taking it creates OUTPUT, and a run refused after that left a folder
    # holding only its lock file.
    train_clips = _clips(list(data or []))
    val_clips = _clips(list(val or []))
    if not train_clips and not synthetic:  # folders given that hold no clip are named: the user looks there first
        where = f"no clips found in {', '.join(printable(str(d)) for d in data)}; " if data else ""
        raise typer.BadParameter(f"{where}give clips to train on, or --synthetic N")
    cfg = None
    if method == "rnn":  # its options are checked before the lock too
        cfg = _rnn_config(
            size=size,
            seq_len=seq_len,
            stride=stride,
            batch=batch,
            lr=lr,
            epochs=epochs,
            seed=seed,
            fps=fps or None,
            init=init,
            anchor=anchor,
            head=head or "gamma",
            objective=objective,
            consistency=consistency,
            temporal=temporal,
            exposure_jitter=exposure_jitter,
            inputs=inputs or "rgb",
            frame_steps=frame_steps,
            steady_weight=steady_weight,
            darken_weight=darken_weight,
            darken_level=darken_level,
        )
    from colonlight import TRAIN_LOCK, output_lock

    # Held from the first clip rendered to the last weights written, released when the command ends (click closes
    # the context); a folder another run holds is an OutputError, one line from the console script.
    ctx.with_resource(output_lock(output, TRAIN_LOCK))
    command = invocation(ctx)
    extra: dict[str, object] = {"command": command}
    if synthetic:
        train_clips += _synthetic_clips(
            output,
            synthetic,
            synthetic_seed,
            synthetic_frames,
            "train",
            synthetic_size,
            synthetic_steady,
            synthetic_occluders,
            synthetic_clean_seeds,
        )
        extra["data"] = (
            f"synthetic: {synthetic} clips x {synthetic_frames} frames rendered at {synthetic_size}px, "
            f"seeds {synthetic_seed}..{synthetic_seed + synthetic - 1}, generator split 'train', "
            f"about {synthetic_steady:.0%} of them with steady lighting (no disturbance)"
            + (
                f", about {synthetic_occluders:.0%} forced to have a close-occluder moment"
                if synthetic_occluders
                else ""
            )
            + (
                f", about {synthetic_clean_seeds:.0%} with two undisturbed first frames"
                if synthetic_clean_seeds
                else ""
            )
        )
        if synthetic_val and not val_clips:
            val_clips = _synthetic_clips(
                output,
                synthetic_val,
                synthetic_seed + synthetic,
                synthetic_frames,
                "val",
                synthetic_size,
                synthetic_steady,
                synthetic_occluders,
                synthetic_clean_seeds,
            )
            extra["validation_data"] = (
                f"synthetic: {synthetic_val} clips, seeds {synthetic_seed + synthetic}.."
                f"{synthetic_seed + synthetic + synthetic_val - 1}"
            )
    if not val_clips and len(train_clips) > 1:
        val_clips = [train_clips.pop()]
    if cfg is None:
        _train_zerodce(train_clips, method, output, name, epochs, size, batch, lr, seed, fps, extra)
        return
    # Imported here, not at the top: other commands (enhance above all) do without torch's training side and kornia.
    from colonlight import train_model

    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("loss {task.fields[loss]:.4f}"),
        TimeRemainingColumn(),
        console=console,
    ) as progress:
        task = progress.add_task("epoch", total=None, loss=float("nan"))

        def on_step(epoch: int, step: int, steps: int, loss: float) -> None:
            progress.update(task, description=f"epoch {epoch + 1}/{epochs}", total=steps, completed=step, loss=loss)

        def on_epoch(rec: EpochRecord) -> None:
            val_txt = f"{rec.val_loss:.4f}" if rec.val_loss is not None else "-"
            progress.console.print(
                f"epoch {rec.epoch}: train loss {rec.train_loss:.4f}, val loss {val_txt}, {rec.seconds:.0f} s"
            )

        try:
            result = train_model(
                train_clips,
                val_clips,
                output,
                cfg,
                name=name,
                card_extra=extra,
                resume=resume,
                on_step=on_step,
                on_epoch=on_epoch,
                on_skip=_skip_line,
            )
        except OSError as exc:  # a disk that fills mid-run: the epochs saved so far stay, the rerun resumes
            _write_failed(exc, output)
    _wrote(result.weights)
    _exit_if_skipped(result.skipped, " (listed in the card)")


def _check_numbers(fps: float, lr: float, **weights: float) -> None:
    """Usage errors for values no run can use, before anything is read or rendered: an fps outside enhance's
    range, a learning rate that is not a finite number in (0, 1e30] (a larger one overflowed inside the optimizer,
    a traceback), a loss weight that is not finite."""
    check_fps(fps)
    if not (math.isfinite(lr) and 0 < lr <= MAX_LEARNING_RATE):
        raise typer.BadParameter(
            f"must be a finite number above 0 and at most {MAX_LEARNING_RATE:g}, got {lr:g}", param_hint="--lr"
        )
    for name, value in weights.items():
        if not math.isfinite(value):
            raise typer.BadParameter(
                f"must be a finite number, got {value:g}", param_hint="--" + name.replace("_", "-")
            )


#: Longest --name: the file system's 255 bytes a name, less what the weights' temporary adds around it
#: (``.NAME-epoch001.safetensors.XXXXXXXX.colonlight-tmp.safetensors``: 58). A longer one trained a whole epoch,
#: then failed naming a temporary file.
_MAX_NAME_BYTES = 190


def _check_name(name: str) -> None:
    """A usage error for a ``--name`` that is no plain file name: empty (the weights would be a hidden
    ``.safetensors``), hidden, a path (``../x`` would write outside OUTPUT), or too long for its files."""
    if not name or name.startswith(".") or "/" in name or "\\" in name or "\0" in name:
        raise typer.BadParameter(
            f"must be a plain file name (no folder, not hidden), got {name!r}", param_hint="--name"
        )
    if len(os.fsencode(name)) > _MAX_NAME_BYTES:
        raise typer.BadParameter(
            f"must be at most {_MAX_NAME_BYTES} bytes long (its files' temporaries must fit the file system's "
            f"255), got {len(os.fsencode(name))}",
            param_hint="--name",
        )


def _check_output(output: Path) -> None:
    """A usage error, before anything is rendered or trained, for an OUTPUT that can never be the run's folder:
    a file, a path under one (it was a traceback after the first epoch), or a name too long. Nothing is created
    here."""
    for path in (output, *output.parents):
        try:
            exists = path.exists()
        except OSError as exc:  # a name past NAME_MAX (ENAMETOOLONG): Path.exists raises it, a traceback before
            raise typer.BadParameter(
                f"{output}: cannot be used: {exc.strerror or exc}", param_hint="--output"
            ) from None
        if exists:
            if not path.is_dir():
                what = "the output path is a file" if path == output else f"{path} is a file"
                raise typer.BadParameter(f"{output}: {what}, not a folder", param_hint="--output")
            if not os.access(path, os.W_OK | os.X_OK):
                raise typer.BadParameter(
                    f"{output}: {path} cannot be written (permission denied)", param_hint="--output"
                )
            return


def _write_failed(exc: OSError, output: Path) -> NoReturn:
    """One line for a run folder that could not be written (disk full, read-only), exit 1."""
    error_line(f"{exc.filename or output}: cannot write the run: {exc.strerror or exc}")
    raise typer.Exit(1) from None


def _export_epoch(run_dir: Path, epoch: int) -> None:
    """``--export-epoch``: one epoch of a run as weights, or a one-line error (exit 1)."""
    from colonlight import InputError, export_epoch

    with ends_command(FAILED, kinds=(InputError,)):
        result = export_epoch(run_dir, epoch)
    _wrote(result.weights)


def _train_zerodce(
    clips: list[Path],
    variant: str,
    output: Path,
    name: str,
    epochs: int,
    size: int,
    batch: int,
    lr: float,
    seed: int,
    fps: float,
    extra: dict[str, object],
) -> None:
    """Zero-DCE / Zero-DCE++ on every 3rd frame of the clips, without the colour-constancy loss (as the paper did)."""
    from colonlight import InputError, clip_frames, train_zerodce

    skipped: list[str] = []

    def frames() -> Iterator[np.ndarray]:
        for clip in clips:
            try:
                for f in clip_frames(clip, fps=fps or None):
                    if f.index % 3 == 0:
                        yield f.image
            except InputError as exc:  # the clip's frames up to the damage are kept, the others go on
                skipped.append(str(exc))
                _skip_line(str(exc))

    stem = name if name != "colonlight-rnn" else variant
    data = frames()
    first = next(data, None)  # none at all was train_zerodce's ValueError("no training frames"), a traceback
    if first is None:
        why = f"{len(skipped)} of {len(clips)} clips could not be used (the first: {skipped[0]})" if skipped else ""
        error_line(f"no training frames{': ' + why if why else f' in the {len(clips)} clip(s)'}")
        raise typer.Exit(1)
    try:
        result = train_zerodce(
            itertools.chain([first], data),
            variant=variant,
            epochs=epochs,
            lr=lr,
            batch=batch,
            size=size,
            seed=seed,
            out_path=output / f"{stem}.safetensors",
            colour_constancy_weight=0.0,
            name=stem,
            card_extra={**extra, "frames": "every 3rd frame of the training clips"},
            on_epoch=lambda e: console.print(f"epoch {e.epoch}: loss {e.loss:.4f}, {e.seconds:.0f} s"),
        )
    except FloatingPointError as exc:  # diverged: nothing is written
        error_line(f"{exc}: try a lower --lr (this run: {lr:g})")
        raise typer.Exit(1) from None
    except OSError as exc:
        _write_failed(exc, output)
    _wrote(result.weights)
    _exit_if_skipped(skipped, "")


def _wrote(weights: Path) -> None:
    """The weights and card written, their paths shown as they are: an OUTPUT or --name with ``[/]`` in it was
    read as markup (a traceback after the run had written everything)."""
    console.print(
        f"weights: {printable(str(weights))}\ncard:    {printable(str(weights.with_suffix('.json')))}", soft_wrap=True
    )


def _skip_line(reason: str) -> None:
    console.print(f"[red]skipped[/] {printable(reason)}", soft_wrap=True)


def _exit_if_skipped(skipped: list[str], where: str) -> None:
    """The model is written, but not from every clip asked for: say so and exit 1, as enhance does."""
    if skipped:
        error_line(f"{len(skipped)} clip(s) could not be used and were left out{where}")
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    app.command("train")(interruptible(train_cmd))  # SIGTERM as Ctrl-C: temporaries removed, exit 143
