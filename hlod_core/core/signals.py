"""Stop signals as exceptions, for the processes that bake: the command line (`python -m
hlod_core`) and the Blender bake's child process (`python -m hlod_core.bake.run.child`).

SIGTERM (a parent's cancel, `kill`) and SIGHUP (a closed terminal) raise `Terminated` in the main
thread, like Ctrl-C's KeyboardInterrupt and like it not an Exception, so no `except Exception`
swallows it and every context manager unwinds: the bake's worker pool and scratch folder, atomic
writes. The first signal raises; later ones are ignored so that they cannot cut the cleanup short.

An exception raised by a signal handler can land anywhere, even inside the standard library's
lock handling (a thread's start), where it breaks the lock instead of unwinding. Code that starts
threads and processes (the bake) runs inside `stop_signals_held`: there a stop signal (and
Ctrl-C) is only recorded, and raised where the code calls `deliver_held` (its safe points) or
when the block exits.
Why: docs/how-it-works.md#stop-signals-during-a-bake
"""
from __future__ import annotations

import contextlib
import signal
import threading
from typing import Callable, Iterator

#: The signals turned into Terminated (SIGHUP does not exist on Windows).
TERMINATING_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))
#: The signals `stop_signals_held` records: Ctrl-C's and the terminating ones.
STOP_SIGNALS = (signal.SIGINT, *TERMINATING_SIGNALS)


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


class HeldSignals:
    """The stop signals recorded inside one `stop_signals_held` block (module docstring)."""

    def __init__(self, previous: dict[int, Callable]):
        self._previous = previous  # signal -> the Python handler it had before the block
        self._caught: list[int] = []

    def record(self, signum: int, _frame=None) -> None:
        """The handler installed for the block: remember the signal, raise nothing."""
        if signum not in self._caught:
            self._caught.append(signum)

    @property
    def pending(self) -> bool:
        """Whether a signal arrived that has not been delivered yet."""
        return bool(self._caught)

    def deliver(self) -> None:
        """At a safe point: run the recorded signals' own handlers, in arrival order, so that their
        exception (Terminated, KeyboardInterrupt) is raised here. Nothing happens when none came."""
        while self._caught:
            signum = self._caught.pop(0)
            self._previous[signum](signum, None)

    def restore(self) -> None:
        """Put the handlers back as they were before the block (idempotent)."""
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


class _NothingHeld(HeldSignals):
    """Off the main thread signals are not ours to handle: nothing is recorded or delivered."""

    def __init__(self):
        super().__init__({})

    def restore(self) -> None:
        pass


_active: HeldSignals | None = None


@contextlib.contextmanager
def stop_signals_held() -> Iterator[HeldSignals]:
    """Record STOP_SIGNALS instead of running their handlers while the body runs; the body calls
    `deliver()` at safe points, and what is still recorded when it exits is delivered then. Only
    signals with a Python handler are held (a default or ignored one is left alone); only on the
    main thread (elsewhere nothing changes); a block inside another shares the outer one's."""
    global _active
    if threading.current_thread() is not threading.main_thread():
        yield _NothingHeld()
        return
    if _active is not None:
        yield _active
        return
    previous = {sig: handler for sig in STOP_SIGNALS if callable(handler := signal.getsignal(sig))}
    held = HeldSignals(previous)
    for sig in previous:
        signal.signal(sig, held.record)
    _active = held
    try:
        yield held
    finally:
        _active = None
        held.restore()
        held.deliver()


def deliver_held() -> None:
    """At a safe point of code that may run inside `stop_signals_held`: deliver what that block
    recorded (HeldSignals.deliver). Nothing happens outside such a block or off the main thread."""
    if _active is not None and threading.current_thread() is threading.main_thread():
        _active.deliver()
