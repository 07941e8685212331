"""The ``gvt`` command line: a thin typer app over the library, one module per verb.

Verb modules (``record.py``, ``log.py`` ...) share ``common.py`` and never import each other
(tests/test_layering.py); this module assembles them in ``gvt --help`` order. Errors are mapped once, in
:func:`main`: any :class:`~analysis.errors.GvtError` prints its one line and exits with its kind's code
(2 bad input, 1 runtime failure, 3 data lost); a click usage error is one line and exit 2; anything
unexpected is one line and exit 1 (``GVT_DEBUG=1`` re-raises for the traceback). No verb prints a
traceback.
"""

from __future__ import annotations

import os
import sys

import typer

from analysis.errors import GvtError
from daq.cli import analyze, confirm, demo, export, frf, identify, modal, record, replay, report, simulate, sweep
from daq.cli.common import err
from daq.cli.device import device_app
from daq.cli.importing import import_
from daq.cli.log import log_app
from daq.cli.model import model_app
from daq.cli.model_export import model_export
from daq.cli.model_update import model_update

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="gvtlink: ground-vibration-test data acquisition and nonlinear modal analysis.",
)
model_app.command("update")(model_update)  # here, not in model.py: verb modules never import each other
model_app.command("export")(model_export)
app.add_typer(model_app, name="model")
app.add_typer(log_app, name="log")
app.add_typer(device_app, name="device")
app.command("import")(import_)
for verb in (simulate.simulate, sweep.sweep, demo.demo, replay.replay, analyze.analyze, confirm.confirm, record.record,
             report.report, export.export, frf.frf, modal.modal, identify.identify):  # fmt: skip
    app.command()(verb)


def _click_exceptions():
    """The click exception module typer is using (typer >= 0.2x vendors its own copy of click)."""
    try:
        from typer._click import exceptions
    except ImportError:  # older typer: plain click
        from click import exceptions
    return exceptions


def _say(message: str) -> None:
    err.print(message, markup=False, soft_wrap=True)


def _quiet_libraries() -> None:
    """Library loggers that would write their own lines to the terminal are kept off it (``GVT_DEBUG`` lets
    them through). pymodbus logs each reconnect attempt ("Connection to (...) failed", "Repeating....") through
    Python's last-resort handler onto stderr, between the recorder's lines (issue 30); the Modbus driver counts
    and logs every reconnect itself (``/daq/events``), so nothing is lost."""
    import logging

    lg = logging.getLogger("pymodbus")
    if os.environ.get("GVT_DEBUG"):
        return
    if not any(isinstance(h, logging.NullHandler) for h in lg.handlers):
        lg.addHandler(logging.NullHandler())
    lg.propagate = False


def run(argv: list[str] | None = None) -> int:
    """Run ``gvt`` with ``argv`` (default: the command line) and return the exit code; errors are mapped here
    and only here. Tests call this in-process; the console script is :func:`main`."""
    cx = _click_exceptions()
    _quiet_libraries()
    try:
        code = app(args=argv, standalone_mode=False)
        return code if isinstance(code, int) else 0
    except typer.Exit as exc:
        return exc.exit_code
    except cx.UsageError as exc:
        if type(exc).__name__ == "NoArgsIsHelpError":  # the help text has been printed already
            return 2
        cmd = exc.ctx.command_path if exc.ctx is not None else "gvt"
        _say(f"gvt: error: {exc.format_message()} (see '{cmd} --help')")
        return 2
    except typer.Abort:
        _say("gvt: aborted")
        return 130
    except GvtError as exc:
        if os.environ.get("GVT_DEBUG"):
            raise
        _say(f"gvt: error: {exc}")
        return exc.exit_code
    except KeyboardInterrupt:
        _say("gvt: interrupted")
        return 130
    except OSError as exc:  # a file or disk failure no verb foresaw: which file and what, not "internal error"
        if os.environ.get("GVT_DEBUG"):
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        _say(f"gvt: error: {where}{exc.strerror or exc} (set GVT_DEBUG=1 for the traceback)")
        return 1
    except Exception as exc:  # never a traceback to a user
        if os.environ.get("GVT_DEBUG"):
            raise
        _say(f"gvt: internal error: {type(exc).__name__}: {exc} (set GVT_DEBUG=1 for the traceback)")
        return 1


def main() -> None:
    sys.exit(run())


__all__ = ["app", "main", "run"]
