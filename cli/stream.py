"""``colonlight stream SRC``: a live source (capture device, network stream, paced file, standard input) enhanced in
real time into a frame folder, ``gammas.jsonl`` and/or a pipe on standard output."""

from __future__ import annotations

import contextlib
import signal
import sys
from pathlib import Path
from typing import Any, NoReturn

import typer

from colonlight import (
    MethodSpec,
    OptionError,
    network_threads,
    reuse_frame_memory,
)
from colonlight.limits import DEFAULT_FPS, DEFAULT_JPEG_QUALITY, MAX_JPEG_QUALITY, MIN_JPEG_QUALITY
from colonlight.live import (
    BACKOFF_MAX_S,
    BACKOFF_START_S,
    DEFAULT_BUFFER,
    DEFAULT_TIMEOUT_S,
    PIPE_FORMATS,
    LiveStream,
    OutputPlan,
    StreamOptions,
    parse_source,
    prepare_output_dir,
)

from . import options
from .display import console, error_line, printable
from .failures import FAILED, USAGE, ends_command
from .loading import imports_frozen, load_method_or_exit


def _input_options(pairs: list[str]) -> dict[str, str]:
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise typer.BadParameter(f"expected KEY=VALUE, got {pair!r}", param_hint="--input-option")
        out[key] = value
    return out


def _print_devices() -> None:
    from colonlight.live import list_devices

    devices = list_devices()
    if not devices:
        console.print("no capture devices (/dev/video*) on this machine")
    for d in devices:
        console.print(f"{d.path}  {d.name}")


def _summary(summary: Any) -> None:
    """The closing summary, on stderr (stdout may be the pipe)."""

    def ms(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    console.print(
        f"[bold]colonlight stream[/]: frames in {summary.frames_in}, out {summary.frames_out}, "
        f"dropped {summary.frames_dropped} ({summary.frames_decoded} source frames decoded, "
        f"{summary.connections} connection(s), {summary.seconds:.1f} s)",
        soft_wrap=True,
    )
    console.print(
        f"latency arrival -> output: p50 {ms(summary.latency_p50_ms)} ms, p95 {ms(summary.latency_p95_ms)} ms, "
        f"max {ms(summary.latency_max_ms)} ms",
        soft_wrap=True,
    )
    if summary.behind_max_s >= 0.5:
        console.print(
            f"[yellow]decoding fell up to {summary.behind_max_s:.1f} s behind the source's clock[/] "
            "(the machine could not keep up; that backlog waited before the decoder)",
            soft_wrap=True,
        )
    note = f"ended: {summary.end}" if summary.end != "error" else "ended by an error"
    if summary.frames_damaged:
        note += f"; {summary.frames_damaged} undecodable packets skipped"
    console.print(printable(note), soft_wrap=True)


def stream(
    ctx: typer.Context,
    source: str | None = typer.Argument(
        None,
        metavar="SRC",
        help="/dev/videoN, a udp:// tcp:// http:// rtsp:// rtmp:// URL, a video file, or - for a container stream "
        "(MPEG-TS, Matroska, raw H.264) on standard input.",
    ),
    output: Path | None = typer.Option(
        None, "--output", "-o", help="Folder for frames/, gammas.jsonl (one line per frame, flushed) and stream.json."
    ),
    pipe: str | None = typer.Option(
        None, "--pipe", help="Also write the enhanced frames to standard output: y4m | mpegts."
    ),
    fps: float = typer.Option(
        DEFAULT_FPS,
        "--fps",
        envvar="COLONLIGHT_FPS",
        help="Output rate (FFmpeg fps-filter frame choice); 0 keeps every frame.",
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
    frames: bool = typer.Option(
        True, "--frames/--no-frames", help="Write enhanced frames into OUTPUT/frames/ (with --output)."
    ),
    fmt: str = typer.Option(
        "jpg",
        "--format",
        "-f",
        help="Frame image format: jpg (default: at 1080p a PNG costs ~20x the CPU of a JPEG, too much at "
        f"{DEFAULT_FPS:g} fps on 2 cores) | png.",
    ),
    quality: int = typer.Option(
        DEFAULT_JPEG_QUALITY, "--quality", min=MIN_JPEG_QUALITY, max=MAX_JPEG_QUALITY, help="JPEG quality."
    ),
    keep: int = typer.Option(0, "--keep", min=0, help="Keep only the newest N frames in OUTPUT/frames/ (0: all)."),
    content: str = options.Content,
    realtime: bool = typer.Option(
        False,
        "--realtime",
        help="Play a file at its own rate, as a live source (default: as fast as possible, no drops).",
    ),
    drop: str = typer.Option(
        "auto",
        "--drop",
        help="When processing falls behind: oldest (drop the oldest waiting frame) | newest | never (wait; a file's "
        "default) | auto.",
    ),
    buffer: int = typer.Option(
        DEFAULT_BUFFER, "--buffer", min=1, max=64, help="Frames that may wait for processing before drops start."
    ),
    reconnect: bool = typer.Option(
        False,
        "--reconnect",
        help=f"Reopen a lost or ended network stream or device, with backoff ({BACKOFF_START_S:g} s doubling to "
        f"{BACKOFF_MAX_S:g} s); the recurrent state is kept.",
    ),
    timeout: float = typer.Option(
        DEFAULT_TIMEOUT_S, "--timeout", min=0.1, help="Seconds without data before a live source counts as lost."
    ),
    duration: float | None = typer.Option(None, "--duration", min=0.0, help="Stop after this many seconds."),
    input_format: str | None = typer.Option(
        None, "--input-format", help="Force FFmpeg's demuxer (e.g. mpegts, matroska, h264, v4l2)."
    ),
    input_option: list[str] = typer.Option(
        [],
        "--input-option",
        help="KEY=VALUE passed to FFmpeg when opening SRC (repeatable), e.g. video_size=1280x720, framerate=30, "
        "rtsp_transport=udp.",
    ),
    list_devices: bool = typer.Option(False, "--list-devices", help="List the capture devices and exit."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the outputs of an earlier stream in OUTPUT."),
    quiet: bool = options.Quiet,
    debug: bool = options.Debug,
) -> None:
    """Enhance a live stream in real time: one recurrent state for the whole stream, frames dropped (and counted)
    when processing falls behind, latency measured; Ctrl-C ends it cleanly with the summary."""
    if list_devices:
        _print_devices()
        return
    if source is None:
        raise typer.BadParameter("missing SRC (a device, URL, file or -)", param_hint="SRC")
    options.check_method(method)
    if fmt not in ("png", "jpg"):
        raise typer.BadParameter("choose png or jpg", param_hint="--format")
    options.check_fps(fps)

    if pipe is not None and pipe not in PIPE_FORMATS:
        raise typer.BadParameter(f"choose {' or '.join(PIPE_FORMATS)}", param_hint="--pipe")
    if output is None and pipe is None:
        raise typer.BadParameter("nothing to write: give --output DIR and/or --pipe y4m|mpegts")
    if pipe is not None and (state := _unusable(sys.stdout)):
        raise typer.BadParameter(
            f"standard output is {state}: send it to a program (| consumer) or a file", param_hint="--pipe"
        )
    if source == "-" and (state := _unusable(sys.stdin)):
        raise typer.BadParameter(
            f"standard input is {state}: pipe a stream into it (producer | colonlight stream -)", param_hint="SRC"
        )
    try:
        opts = StreamOptions(
            fps=fps or None,
            realtime=realtime,
            drop=drop,
            buffer=buffer,
            reconnect=reconnect,
            timeout_s=timeout,
            duration_s=duration,
            content=content,
        )
    except OptionError as exc:
        raise typer.BadParameter(str(exc)) from exc
    spec = MethodSpec.of(method, **options.method_kwargs(ctx, method)[method])
    with imports_frozen():  # as in `enhance`
        engine = load_method_or_exit(spec, debug)  # a bad checkpoint or absent device: a usage error, as in `enhance`
        with ends_command(FAILED, debug):
            src = parse_source(source, input_format, _input_options(input_option))
        if output is not None:
            with ends_command(USAGE, debug):  # an --output that cannot be used: a usage error, as in `enhance`
                prepare_output_dir(output, overwrite)
    if "torch" in sys.modules:  # the method uses torch: its threads as `enhance` sets them (one for the small net)
        sys.modules["torch"].set_num_threads(network_threads(spec, 1))
    reuse_frame_memory()
    plan = OutputPlan(
        out_dir=output,
        frames=frames,
        format=fmt,
        quality=quality,
        keep=keep,
        pipe=pipe,
        pipe_file=sys.stdout.buffer if pipe else None,
    )
    notify = (
        (lambda message: None)
        if quiet
        else (lambda message: console.print(f"[yellow]{printable(message)}[/]", soft_wrap=True))
    )
    with ends_command(FAILED, debug):
        live = LiveStream(src, engine, opts, plan, notify=notify)

    def on_signal(signum: int, _frame: Any) -> None:
        live.stop("stopped (Ctrl-C)" if signum == signal.SIGINT else "stopped (SIGTERM)")
        signal.signal(signum, signal.SIG_DFL)  # a second Ctrl-C ends at once

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    summary = live.run()
    if pipe is not None:
        _quiet_stdout()
    if summary.error:
        error_line(summary.error)
    # a source never opened: its error line is all; stopped while waiting for one: the summary says so
    if (summary.connections or (summary.end and not summary.error)) and (not quiet or summary.error):
        _summary(summary)
    if output is not None and summary.frames_out:
        console.print(f"outputs: {printable(str(output))}", soft_wrap=True)
    if not live.wait_source_closed(0):
        _end_now(1 if summary.error else 0)
    if summary.error:
        raise typer.Exit(1)


def _unusable(stream: Any) -> str | None:
    """Why a standard stream cannot carry the video ("closed": Python set it to None, the command was started
    without it; "a terminal"), or None when it can."""
    if stream is None:
        return "closed"
    return "a terminal" if stream.isatty() else None


def _end_now(code: int) -> NoReturn:
    """End the process now, everything written and closed: the run left its reader in a read of a network source
    gone silent (up to --timeout), and the interpreter must not be torn down under a thread inside FFmpeg (the
    library's exit hook would instead wait for it)."""
    import logging
    import os

    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:  # None: started with it closed (cli/process_start.py)
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
    os._exit(code)


def _quiet_stdout() -> None:
    """After the pipe's reader has gone, point stdout at /dev/null so the interpreter's last flush cannot fail."""
    import os

    with contextlib.suppress(BrokenPipeError, ValueError, OSError):
        sys.stdout.flush()
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def register(app: typer.Typer) -> None:
    app.command("stream")(stream)
