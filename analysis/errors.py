"""One error family for gvtlink, with the exit code of each kind (architecture.md, "Bad input").

Why here: ``analysis`` is the lowest floor (``drivers`` builds on its rig model, ``daq`` on both; the
layering test forbids the other directions), so the root every floor raises from lives on it, as
python-can keeps ``CanError`` beside ``can/message.py`` and the ``mcap`` package has one ``McapError``.
``gvt``'s ``main()`` maps the family once: an error's ``exit_code`` is the process' exit code and
``str(error)`` its one line (what, where, how to fix).

* :class:`BadInput` (exit 2): the user can fix it — a config, an argument, a path, a file that is not a
  log, a configuration the link cannot carry.
* :class:`RuntimeFailure` (exit 1): something failed while running — a device that stopped answering,
  a writer that could not write.
* :class:`DataLost` (exit 3): the run finished but data the user asked for is missing, and the message
  says which.
"""

from __future__ import annotations


class GvtError(Exception):
    """Root of gvtlink's errors; ``str(err)`` is one line for the user."""

    exit_code: int = 1


class BadInput(GvtError):
    """Input the user can fix (a config, an argument, a file): exit 2."""

    exit_code = 2


class RuntimeFailure(GvtError):
    """A failure while running (a device, the disk, a worker): exit 1."""

    exit_code = 1


class DataLost(GvtError):
    """The run ended, but data is missing (the message says what): exit 3."""

    exit_code = 3


__all__ = ["BadInput", "DataLost", "GvtError", "RuntimeFailure"]
