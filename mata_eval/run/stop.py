"""Stopping a run: SIGINT (Ctrl-C) and SIGTERM raise :class:`Interrupted` in the driver, which
then cancels the queued tasks and kills its workers (:mod:`mata_eval.run.executors`).

The handler raises at once, and also records the signal: an exception raised by a signal
handler can be lost when Python happens to be inside a hook that swallows exceptions (a
``__del__``), so the executors' wait loops call :func:`check` a few times a second and raise it
again. Around a process pool the handler only records it (:func:`deferred`): raised inside the
pool's own code it can leave the pool unable to shut down."""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator

from ..core.errors import Interrupted

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: Seconds between two :func:`check` calls of a waiting executor.
POLL_S = 0.2

_received: list[int] = []  # the stop signal received by the driver, if any
_deferred = False  # inside deferred(): a stop signal is recorded, not raised


def check() -> None:
    """Raise :class:`Interrupted` if a stop signal was received inside :func:`stop_on_signals`."""
    if _received:
        raise Interrupted(_received[0])


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """In the main thread: SIGINT and SIGTERM raise :class:`Interrupted` (the first one; the
    cleanup that follows, stopping the workers, is not interrupted again). Elsewhere: nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        if not _received:
            _received.append(signum)
            if not _deferred:
                raise Interrupted(signum)

    previous = {s: signal.signal(s, stop) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _received.clear()


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Within: a stop signal is only recorded; the code inside polls :func:`check`, and leaving
    raises it. For a driver that waits on a library's internals (a process pool forking its
    workers, its queues and threads), which an exception raised at an arbitrary bytecode can
    leave inconsistent: the pool's manager thread not started yet, a fork hook interrupted."""
    global _deferred
    previous, _deferred = _deferred, True
    try:
        yield
    finally:
        _deferred = previous
    check()
