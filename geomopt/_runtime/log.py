"""geomopt's messages as :mod:`logging` records, and where a progress bar can be drawn.

Every message the library itself emits goes to the ``geomopt`` logger, never to a stream
directly: the end of each outer iteration, an atlas's stages, a comparison's runs at INFO,
each iteration's line at DEBUG (logger ``geomopt.iterations``).  The library adds only a
:class:`logging.NullHandler`, so nothing is printed until the host application configures
logging (``logging.basicConfig(level=logging.INFO)`` shows the outer iterations;
``logging.getLogger("geomopt").setLevel(logging.WARNING)`` mutes them again).  The command
line attaches :class:`StderrHandler` (:func:`attach_stderr`) and so keeps its lines.
"""

from __future__ import annotations

import contextlib
import logging
import sys

__all__ = ["logger", "iteration_logger", "StderrHandler", "attach_stderr", "in_notebook", "bar_wanted"]

#: the library's logger: outer iterations, stages and runs at INFO
logger = logging.getLogger("geomopt")
logger.addHandler(logging.NullHandler())
#: one line per iteration at DEBUG (a child of :data:`logger`)
iteration_logger = logging.getLogger("geomopt.iterations")


class StderrHandler(logging.StreamHandler):
    """A handler writing the bare message to the *current* ``sys.stderr`` (looked up at each
    record, so that a replaced stderr, e.g. pytest's capture, receives it)."""

    def __init__(self):
        super().__init__(sys.stderr)
        self.setFormatter(logging.Formatter("%(message)s"))

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):  # StreamHandler's constructor assigns it; the lookup above wins
        pass


@contextlib.contextmanager
def attach_stderr(level: int = logging.DEBUG):
    """Within the block, :data:`logger`'s records at ``level`` and above go to stderr as bare
    lines (the command line's progress); the logger's level and handlers are restored after."""
    handler, old = StderrHandler(), logger.level
    handler.setLevel(level)
    logger.addHandler(handler)
    logger.setLevel(min(level, old) if old else level)
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)


def in_notebook() -> bool:
    """True inside a Jupyter kernel (an IPython shell with a kernel app), where a widget bar
    is drawn in the cell instead of lines in its log."""
    shell = sys.modules.get("IPython")
    if shell is None:
        return False
    try:
        ip = shell.get_ipython()
    except Exception:  # an IPython module in a state we do not know: no widgets
        return False
    return ip is not None and "IPKernelApp" in getattr(ip, "config", {})


def bar_wanted(stream) -> bool:
    """A progress bar is drawn on a terminal and in a notebook, never into a pipe or a file."""
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty is not None and isatty()) or in_notebook()
    except ValueError:  # a closed stream
        return False
