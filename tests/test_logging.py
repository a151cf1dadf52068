"""A quiet, loggable library (issue 49): progress=True draws a bar on a terminal or in a
notebook and prints nothing into a pipe; every message is a record on the ``geomopt`` logger,
which the application routes or mutes; the command line keeps its lines."""

import io
import logging
import subprocess
import sys

import pytest

import geomopt
from geomopt._runtime import log
from geomopt.mesh import generators as G
from geomopt.solvers import Progress


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _solve(**kw):
    t = G.rotated_interior(*G.square_mesh(6), 90.0)
    return geomopt.untangle(t.problem(), t.x0, **kw)


def test_progress_prints_nothing_into_a_pipe_by_default(capfd):
    res = _solve()  # the default progress=True
    assert res.success
    assert capfd.readouterr() == ("", "")


def test_records_reach_a_configured_logger_iterations_at_debug(caplog):
    caplog.set_level(logging.INFO, logger="geomopt")
    geomopt.minimize(*_minimize_problem(), progress=True)
    assert not [r for r in caplog.records if r.name == "geomopt.iterations"]  # INFO: no iteration lines
    caplog.clear()
    caplog.set_level(logging.DEBUG, logger="geomopt")
    res = geomopt.minimize(*_minimize_problem(), progress=True)
    lines = [r for r in caplog.records if r.name == "geomopt.iterations"]
    assert len(lines) == res.stats.iterations and all(r.levelno == logging.DEBUG for r in lines)
    assert lines[0].getMessage().startswith("iter    1  mean energy")


def test_a_muted_logger_gets_nothing(caplog):
    caplog.set_level(logging.DEBUG)
    logging.getLogger("geomopt").setLevel(logging.WARNING)
    try:
        _solve()
    finally:
        logging.getLogger("geomopt").setLevel(logging.NOTSET)
    assert not [r for r in caplog.records if r.name.startswith("geomopt")]


def _minimize_problem():
    V, F = G.disk_mesh(4)
    b = G.boundary_vertices(F, len(V))
    target = V.copy()
    target[b] = V[b] * [1.3, 0.8]
    return geomopt.Objective(geomopt.Problem.planar(V, F, b, target[b]), "symmetric_dirichlet"), V


def test_a_bar_on_a_terminal_and_none_into_a_pipe():
    term, pipe = _Terminal(), io.StringIO()
    assert Progress(stream=term)._bar is not None
    assert Progress(stream=pipe)._bar is None
    assert Progress(stream=term, iterations=False)._bar is None


def test_a_notebook_gets_a_bar(monkeypatch):
    class Shell:
        config = {"IPKernelApp": {}}

    class IPython:
        @staticmethod
        def get_ipython():
            return Shell()

    assert not log.in_notebook()
    monkeypatch.setitem(sys.modules, "IPython", IPython)
    assert log.in_notebook() and log.bar_wanted(io.StringIO())
    monkeypatch.setattr(Shell, "config", {})  # a plain IPython terminal: no kernel, no widget
    assert not log.in_notebook()


def test_the_stderr_handler_follows_a_replaced_stderr(monkeypatch):
    with log.attach_stderr(logging.INFO):
        err = io.StringIO()
        monkeypatch.setattr(sys, "stderr", err)
        log.logger.info("hello")
        log.logger.debug("not shown")
    log.logger.info("after: not shown")
    assert err.getvalue() == "hello\n"
    assert not any(isinstance(h, log.StderrHandler) for h in log.logger.handlers)


@pytest.mark.parametrize("quiet", [False, True])
def test_the_command_line_keeps_its_lines(tmp_path, quiet):
    """The CLI attaches stderr to the logger: outer iterations and (in a pipe) iterations are
    its lines; --quiet leaves them out."""
    V, F = G.square_mesh(6)
    t = G.rotated_interior(V, F, 90.0)
    src = tmp_path / "m.obj"
    src.write_text("".join(f"v {x} {y} 0\n" for x, y in V) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in F))
    cmd = [sys.executable, "-m", "geomopt", "param", str(src), "-o", str(tmp_path / "out.obj")] + (["--quiet"] if quiet else [])
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    iters = [line for line in run.stderr.splitlines() if line.startswith("iter ")]
    assert (not iters) if quiet else iters, run.stderr
