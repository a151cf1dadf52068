"""Where a ``geomopt`` process spends its wall time: the ``timing`` split of ``--json``.

The clock starts at process start (Linux: the process's start time in ``/proc``, which counts
the interpreter's own start-up; elsewhere the first import of geomopt), so the phases add up
to what a user waits for:

* ``import``: process start until the command's modules (JAX, the solvers) are imported;
* ``read``: reading and checking the input;
* ``compile``: JAX tracing, lowering and XLA compilation or loading from the persistent cache
  (summed from JAX's own duration events; it happens inside set-up, whose figure excludes it,
  except for a program first used inside the loop, which ``solve`` also counts);
* ``setup``: the solver's set-up less ``compile`` (scaling, patterns, factorizations);
* ``cut``, ``flatten``, ``pack``: an atlas's stages (``geomopt param`` on a surface that is not a
  disk): the seam graph, the charts' flattenings and splits, the packing with its certificate;
* ``solve``: the solve loop;
* ``certify``: the exact checks of the result (orientation predicates, branch points);
* ``write``: writing the output, reading it back and certifying the file;
* ``figures``: drawing, encoding and writing the pictures (``--png``);
* ``total``: process start until the summary is made; ``other``: what the phases leave.
"""

from __future__ import annotations

import os
import threading
import time

_T_IMPORT = time.perf_counter()
_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
           "/jax/core/compile/backend_compile_duration")
_lock = threading.Lock()
_compile = {"seconds": 0.0, "listening": False}


def process_start() -> float:
    """The ``time.perf_counter()`` reading at the start of this process (Linux: from
    ``/proc/self/stat``, 10 ms resolution; elsewhere: when geomopt was first imported)."""
    try:
        with open("/proc/self/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")  # field 22: start, ticks after boot
        with open("/proc/uptime", "rb") as fh:
            uptime = float(fh.read().split()[0])
        now = time.perf_counter()
        age = uptime - started
        return now - age if 0.0 <= age < now - _T_IMPORT + 60.0 else _T_IMPORT
    except (OSError, ValueError, IndexError):
        return _T_IMPORT


def _on_duration(event, duration, **kwargs):
    if event in _EVENTS:
        with _lock:
            _compile["seconds"] += duration


def compile_seconds() -> float:
    """Seconds JAX spent tracing, lowering and compiling (or loading compiled programs) since
    the first call of this function, which starts the count (it imports JAX)."""
    with _lock:
        if not _compile["listening"]:
            import jax.monitoring

            jax.monitoring.register_event_duration_secs_listener(_on_duration)
            _compile["listening"] = True
        return _compile["seconds"]


class Split:
    """Phase seconds of one process, from :func:`process_start`.

    ``with split.phase("read"): ...`` adds the block's wall time to a phase; :meth:`add` adds
    a measured duration; :meth:`summary` gives the rounded dict with ``total`` and ``other``.
    """

    def __init__(self):
        self.start = process_start()
        self.seconds: dict[str, float] = {}

    def add(self, name: str, seconds: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + max(float(seconds), 0.0)

    def mark_imported(self) -> None:
        """End the ``import`` phase now (process start until here)."""
        self.seconds["import"] = time.perf_counter() - self.start

    def phase(self, name: str):
        return _Phase(self, name)

    def summary(self) -> dict:
        total = time.perf_counter() - self.start
        out = {k: round(v, 4) for k, v in self.seconds.items()}
        out["total"] = round(total, 4)
        out["other"] = round(max(total - sum(self.seconds.values()), 0.0), 4)
        return out


class _Phase:
    def __init__(self, split, name):
        self.split, self.name = split, name

    def __enter__(self):
        self.t = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.split.add(self.name, time.perf_counter() - self.t)
        return False
