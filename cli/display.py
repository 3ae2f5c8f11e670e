"""Terminal display: live progress of clips and frames, the summary table, one-line errors."""

from __future__ import annotations

import os
import sys
import time
import unicodedata
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table
from typer.core import TyperGroup

from colonlight import ClipOutcome, PathProblem


class ReportConsole(Console):
    """A console whose reader may go away (``| head -1``, a pager quit early): the report stops, the work goes on.
    rich's default ends the process (SystemExit 1) from inside whatever printed, which stopped a batch between two
    clips, silently, with the rest undone."""

    def on_broken_pipe(self) -> None:
        self.quiet = True  # nothing more is rendered
        null = os.open(os.devnull, os.O_WRONLY)
        try:  # what else writes there (Python at exit, a library) writes nowhere, without an error
            os.dup2(null, self.file.fileno())
        except (OSError, ValueError, AttributeError):  # not a file with a descriptor: the quiet console suffices
            pass
        finally:
            os.close(null)


console = ReportConsole(stderr=True, highlight=False)
out = ReportConsole(highlight=False)


#: Unicode categories never printed as they are: controls (a newline), formats (a right-to-left override),
#: line and paragraph separators, surrogates, private and unassigned code points.
_UNSHOWN = frozenset({"Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"})


def _untyped_flags(params: list[Any]) -> list[Any]:
    for param in params:
        if getattr(param, "is_flag", False) and param.metavar is None:
            param.metavar = ""  # shown in the type column as it is: nothing
    return params


class FlagsWithoutType(TyperGroup):
    """The command group, whose ``--help`` shows no value type beside a flag: typer prints ``<bool>`` beside
    ``--quiet`` and ``--help``, which take no value (``--video/--no-video`` is the value)."""

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        command = super().get_command(ctx, cmd_name)
        if command is not None:
            _untyped_flags(command.get_params(ctx))  # with its --help
        return command

    def get_params(self, ctx: Any) -> Any:
        return _untyped_flags(super().get_params(ctx))


def printable(text: str) -> str:
    """``text`` (a message naming paths) as one line any terminal shows as it is.

    Bytes of a name that are not UTF-8 (surrogate escapes, as ``os.fsdecode`` gives them) show as ``\\xNN``,
    control characters (a newline in a file name) as escapes, characters the terminal's encoding lacks (``ü``
    on an ASCII terminal) as ``\\xNN``/``\\uNNNN``, and ``[`` cannot start rich markup.
    """
    try:
        text = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a surrogate that no file name gives: escape it as it is
        text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    if not text.isprintable():
        text = "".join(
            c.encode("unicode_escape").decode("ascii") if unicodedata.category(c) in _UNSHOWN else c for c in text
        )
    encoding = console.encoding or "utf-8"
    try:
        text = text.encode(encoding, "backslashreplace").decode(encoding)
    except LookupError:  # an encoding Python does not know: keep ASCII
        text = text.encode("ascii", "backslashreplace").decode("ascii")
    return escape(text)


def error_line(message: str) -> None:
    """One line on stderr, no traceback."""
    try:
        console.print(f"[bold red]error:[/] {printable(message)}", soft_wrap=True)
    except MemoryError:  # rich loads modules as it renders: under a memory limit that loaded torch half-way, text
        sys.stderr.write(f"error: {message.encode('ascii', 'backslashreplace').decode('ascii')}\n")


def problem_line(problem: PathProblem) -> None:
    """A path that was not a clip and was not searched (a folder that cannot be read, a link loop)."""
    label = "[red]failed[/] " if problem.failed else "[dim]skipped[/]"
    console.print(f"{label} {printable(problem.message)}", soft_wrap=True)


class FpsColumn(TextColumn):
    """Frames per second of a task."""

    def __init__(self) -> None:
        super().__init__("")

    def render(self, task: Any) -> Any:  # noqa: D102
        from rich.text import Text

        if task.fields.get("unit") != "frames":
            return Text("")
        speed = task.finished_speed or task.speed
        return Text(f"{speed:5.1f} fps" if speed else "   -- fps", style="cyan")


class BatchDisplay:
    """Progress of a batch: one bar for clips, one per running clip for its frames (fps, ETA).

    With ``quiet`` nothing live is drawn: a line per finished clip instead, for logs. The bars are drawn from the
    first clip's start or outcome on, so that a batch stopped before any clip (a cluster that cannot be reached)
    prints its one-line error without an empty bar above it.
    """

    def __init__(self, n_clips: int, quiet: bool = False) -> None:
        self.quiet = quiet
        self.progress: Progress | None = None
        self.clip_tasks: dict[str, TaskID] = {}
        self.started = time.perf_counter()
        if not quiet:
            self.progress = Progress(
                TextColumn("{task.description}", justify="left"),
                BarColumn(),
                MofNCompleteColumn(),
                FpsColumn(),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                console=console,
                transient=False,
            )
            self.overall = self.progress.add_task("[bold]clips", total=n_clips)

    def __enter__(self) -> BatchDisplay:
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.progress and self.progress.live.is_started:  # stop() of bars never drawn would print a blank line
            self.progress.stop()

    def event(self, event: str, clip: str, data: dict[str, Any]) -> None:
        if not self.progress:
            return
        self.progress.start()  # from the first event on; later calls do nothing
        if event == "start":
            self.clip_tasks[clip] = self.progress.add_task(
                f"  {printable(clip)}", total=data.get("total"), unit="frames"
            )
        elif event == "frames" and clip in self.clip_tasks:
            self.progress.update(self.clip_tasks[clip], completed=data["done"])
        elif event == "end" and clip in self.clip_tasks:
            self.progress.remove_task(self.clip_tasks.pop(clip))

    def outcome(self, o: ClipOutcome) -> None:
        if self.progress:
            self.progress.start()
            self.progress.advance(self.overall)
        if o.status == "failed":
            self._print(f"[red]failed[/]  {printable(o.error or o.name)}")
        elif o.skipped:
            self._print(f"[dim]skipped[/] {printable(o.name)} (complete)")
        else:
            self._print(f"[green]done[/]    {printable(o.name)}: {o.frames} frames in {o.seconds:.1f} s")
        for line in o.warnings:
            self._print(f"[yellow]warning[/] {printable(str(o.source))}: {printable(line)}")

    def _print(self, text: str) -> None:
        if self.progress:
            self.progress.console.print(text, soft_wrap=True)
        else:
            console.print(text, soft_wrap=True)


def summary(outcomes: list[ClipOutcome], seconds: float, out_dir: str) -> None:
    """The final table: clips done/skipped/failed, frames, throughput."""
    done = [o for o in outcomes if o.status == "done" and not o.skipped]
    skipped = [o for o in outcomes if o.skipped]
    failed = [o for o in outcomes if o.status == "failed"]
    frames = sum(o.frames for o in done)
    table = Table(title="colonlight enhance", show_header=True, header_style="bold")
    for col in ("clips", "enhanced", "skipped", "failed", "frames", "seconds", "frames/s"):
        table.add_column(col, justify="right")
    table.add_row(
        str(len(outcomes)),
        str(len(done)),
        str(len(skipped)),
        str(len(failed)),
        str(frames),
        f"{seconds:.1f}",
        f"{frames / seconds:.1f}" if seconds > 0 else "-",
    )
    console.print(table)
    console.print(f"outputs: {printable(out_dir)}", soft_wrap=True)
    sys.stderr.flush()
