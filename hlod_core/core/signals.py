"""Stop signals as exceptions, for the processes that bake: the command line (`python -m
hlod_core`) and the Blender bake's child process (`python -m hlod_core.bake.child`).

SIGTERM (a parent's cancel, `kill`) and SIGHUP (a closed terminal) raise `Terminated` in the main
thread, like Ctrl-C's KeyboardInterrupt and like it not an Exception, so no `except Exception`
swallows it and every context manager unwinds: the bake's worker pool and scratch folder, atomic
writes. The first signal raises; later ones are ignored so that they cannot cut the cleanup short.
"""
from __future__ import annotations

import contextlib
import signal
import threading

#: The signals turned into Terminated (SIGHUP does not exist on Windows).
TERMINATING_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


class Terminated(BaseException):
    """A terminating signal arrived; `signum` says which."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def signals_as_exceptions():
    """Install the handlers for the body's duration and restore the old ones after. Signal handlers
    can only be set from the main thread: elsewhere (an embedding host) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    raised = False

    def handler(signum, _frame):
        nonlocal raised
        if not raised:
            raised = True
            raise Terminated(signum)

    previous = {sig: signal.signal(sig, handler) for sig in TERMINATING_SIGNALS}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
