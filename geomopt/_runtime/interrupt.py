"""Interrupts that cannot be lost: a signal handler that records SIGINT, SIGTERM and SIGHUP
before raising :class:`Interrupted`, and :func:`raise_pending` for the safe points that raise
it again.

Python runs a signal handler in the main thread between two bytecodes, wherever that thread
is; when it is inside a callback whose exceptions Python ignores (a garbage-collection
callback, such as JAX's, a ``__del__``, a weakref callback), the ``KeyboardInterrupt`` is
printed as "Exception ignored in ..." and lost.  The signal stays recorded here: the solver
loop (every iteration), the atomic writers (before renaming an output into place) and the
command line (after the command) call :func:`raise_pending`, so such a run still ends as
interrupted and writes nothing.  A signal that arrives during an import is only recorded (see
:func:`_importing`) and raised at the next of those points.
"""

from __future__ import annotations

import contextlib
import signal

__all__ = ["Interrupted", "handled", "raise_pending", "pending", "deliberate"]

#: the signals the command line turns into :class:`Interrupted`
SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))

_recorded: list[int] = []


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP raised as an interrupt; ``signum`` is the signal's number."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


def _record_and_raise(signum, frame):
    _recorded.append(signum)
    if not _importing(frame):
        raise Interrupted(signum)


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside an import: an exception raised there can leave a C
    extension half initialised (NumPy turns it into an ImportError; others abort the process),
    so the signal is only recorded and raised at the next safe point."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def pending() -> int | None:
    """The first signal recorded by :func:`handled`'s handler, or ``None``."""
    return _recorded[0] if _recorded else None


def raise_pending() -> None:
    """Raise :class:`Interrupted` again if a signal was recorded (its first raise may have been
    swallowed); nothing otherwise.  Cheap: call it at every safe point."""
    if _recorded:
        raise Interrupted(_recorded[0])


@contextlib.contextmanager
def handled():
    """While the block runs (main thread only), SIGINT, SIGTERM and SIGHUP are recorded and
    raised as :class:`Interrupted`; the previous handlers and an empty record afterwards.
    Elsewhere than the main thread it changes nothing."""
    previous = {}
    try:
        for signum in SIGNALS:
            previous[signum] = signal.signal(signum, _record_and_raise)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        _recorded.clear()


@contextlib.contextmanager
def deliberate():
    """Inside the block, code that caught an interrupt writes what it still must (a batch's
    summary of what finished): a recorded signal does not stop the atomic writers there; it is
    recorded again afterwards, so the run still ends as interrupted.  A new signal inside the
    block raises as ever."""
    saved = list(_recorded)
    _recorded.clear()
    try:
        yield
    finally:
        _recorded[:0] = saved
