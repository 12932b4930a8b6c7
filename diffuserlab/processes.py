"""How a child process ended, in people's words: one wording for the window's
messages (``gui.messages``) and the processes' own logs
(:mod:`instrument.live_process`, ``instrument.batch_process``)."""

from __future__ import annotations

import signal

__all__ = ["how_it_ended"]


def how_it_ended(exit_status: int | None) -> str:
    """How a process ended, in an operator's words.

    Parameters
    ----------
    exit_status : int or None
        Its exit code, or minus the signal that ended it (as
        ``multiprocessing.Process.exitcode``); None: not known.

    Returns
    -------
    str
        ``"it was killed (signal 9, SIGKILL)"``, ``"it exited with status 1"``, ...
    """
    if exit_status is None:
        return "it stopped answering"
    if exit_status < 0:
        try:
            name = f", {signal.Signals(-exit_status).name}"
        except ValueError:
            name = ""
        return f"it was killed (signal {-exit_status}{name})"
    if exit_status > 128:
        try:
            return f"it ended on {signal.Signals(exit_status - 128).name}"
        except ValueError:
            pass
    return f"it exited with status {exit_status}"
