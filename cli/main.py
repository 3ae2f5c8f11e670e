"""Entry point: ``colonlight <command>``; one module per command, registered here.

Exit codes: 0 all good, 1 some inputs failed (or an expected error), 2 usage error. Expected failures print one
line; ``--debug`` (or ``COLONLIGHT_DEBUG=1``) shows tracebacks.
"""

from __future__ import annotations

import sys

import typer

from colonlight import ColonlightError, OptionError, __version__

from . import content, demo, enhance, evaluate, export, info, stream, synth, train
from .display import FlagsWithoutType, error_line
from .failures import FAILED, USAGE
from .interrupts import INTERRUPTED
from .process_start import debug_requested, fill_closed_standard_streams, refuse_a_deleted_working_folder

app = typer.Typer(
    name="colonlight",
    cls=FlagsWithoutType,
    help="Consistent lighting for colonoscopy video (Zhang et al., IPMI 2021): enhance, train, synthesise, serve.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"colonlight {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    """colonlight: consistent lighting for colonoscopy video."""


for module in (enhance, stream, demo, synth, train, info, evaluate, export, content):
    module.register(app)

try:  # the service's command, when its module is present
    from . import serve

    serve.register(app)
except ImportError:  # pragma: no cover
    pass


def run() -> None:
    """Console-script entry: run the app, turning expected errors into one line and exit code 1."""
    fill_closed_standard_streams()  # (again: ``python -m colonlight_cli.main`` starts here)
    refuse_a_deleted_working_folder()
    debug = debug_requested()
    try:
        app()
    except ColonlightError as exc:
        if debug:
            raise
        error_line(str(exc))
        sys.exit(USAGE if isinstance(exc, OptionError) else FAILED)  # a bad value the user gave is a usage error
    except KeyboardInterrupt:
        error_line(INTERRUPTED)
        sys.exit(130)
    except SystemExit as exc:
        # typer turns Ctrl-C inside a command into a silent exit 130 (Exit raised from the KeyboardInterrupt);
        # commands that handle the signal themselves (enhance, stream) say so and raise Exit(130) from None
        if isinstance(exc.__context__, typer.Exit) and isinstance(exc.__context__.__cause__, KeyboardInterrupt):
            error_line(INTERRUPTED)
        raise


if __name__ == "__main__":
    run()
