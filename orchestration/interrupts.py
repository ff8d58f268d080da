"""Stopping a run cleanly on SIGINT, SIGTERM or SIGHUP.

A signal that arrived inside an FMU's doStep would surface as that FMU's failure (pythonfmu turns the
exception into fmi2Error), and SIGTERM/SIGHUP would end the process with the summary still "running".
:func:`deferred_interrupts` turns the first such signal into a request that the run loop honours
between two steps (:meth:`StopRequest.check`), so the rows are flushed, the summary says
"interrupted" and why, and the temporary folders are removed; a second signal interrupts at once.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

#: The signals that stop a run: Ctrl-C, `kill`, and a closed terminal (SIGHUP is not on Windows).
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class Interrupted(KeyboardInterrupt):
    """The run was stopped by a signal; ``signal_number`` says which (exit code 128 + it, by convention)."""

    def __init__(self, signal_number: int) -> None:
        self.signal_number = signal_number
        super().__init__(f"interrupted by {signal.Signals(signal_number).name}")


class StopRequest:
    """The first stop signal received, if any; :meth:`check` raises :class:`Interrupted` once one came."""

    def __init__(self) -> None:
        self.signal_number: int | None = None

    def _receive(self, number: int, frame) -> None:
        if self.signal_number is not None:  # a second signal: the user means now
            raise Interrupted(number)
        self.signal_number = number

    def check(self) -> None:
        if self.signal_number is not None:
            raise Interrupted(self.signal_number)


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[StopRequest]:
    """Within the block, a stop signal sets the yielded request instead of ending the process.

    Signal handlers can only be set in the main thread; elsewhere the request never fires and the
    signals keep their handlers.
    """
    request = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request
        return
    previous = {number: signal.signal(number, request._receive) for number in STOP_SIGNALS}
    try:
        yield request
    finally:
        for number, handler in previous.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)
