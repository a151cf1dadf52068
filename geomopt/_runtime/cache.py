"""JAX set-up shared by the API and the CLI: the persistent compilation cache.

Compiled XLA programs are kept on disk, so a second process (a notebook restart, the next
``geomopt param`` call, another mesh of the same size bucket: :mod:`geomopt._runtime.padding`) loads
them instead of compiling again.

Where the cache lives, in order:

1. :func:`set_cache_dir` (``geomopt.set_cache_dir(path)``; ``None`` turns it off);
2. the environment variable ``GEOMOPT_CACHE_DIR`` (``off``, ``0``, ``none`` or an empty value
   turn it off);
3. ``$XDG_CACHE_HOME/geomopt/jax``, else ``~/.cache/geomopt/jax``.

A folder that cannot be created or written is used read-only (programs already there are
loaded, none is written); a write that fails later (a full disk) is skipped silently.  Never
point it at a folder that others can write: loading a program from it runs that program.

:func:`configure` runs when geomopt is imported and does not import JAX (start-up of
``geomopt --help``): when JAX is not imported yet it sets JAX's own environment variables
(``JAX_COMPILATION_CACHE_DIR``...), read once when JAX is imported, so
child processes inherit them; otherwise it updates ``jax.config``.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import warnings

from .errors import ParameterError

ENV = "GEOMOPT_CACHE_DIR"
_OFF = ("", "0", "off", "none", "false", "no")
#: never write: a read-only cache folder is only read
_NEVER = 1e12

_lock = threading.Lock()
_state = {"dir": None, "writable": False, "hits": 0, "requests": 0, "bypassed": 0, "listening": False,
          "pruned": False}


def default_dir() -> str | None:
    """The cache folder from ``GEOMOPT_CACHE_DIR`` or the user cache folder; None when off."""
    value = os.environ.get(ENV)
    if value is not None:
        return None if value.strip().lower() in _OFF else os.path.expanduser(value)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "geomopt", "jax")


def _writable(path: str) -> bool:
    """Create ``path`` if needed and check that a file can be written there."""
    try:
        os.makedirs(path, exist_ok=True)
        probe = os.path.join(path, f".probe-{os.getpid()}-{threading.get_ident()}")
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600))
        os.unlink(probe)
        return True
    except OSError:
        return False


def _settings(path, writable) -> dict:
    """JAX configuration values for a cache at ``path`` (None: off)."""
    if path is None:
        return {"jax_enable_compilation_cache": False}
    # cache every program (small ones load in ~1 ms, compile in 10-100 ms); a read-only
    # folder gets a threshold no compilation reaches, so nothing is written there
    return {"jax_enable_compilation_cache": True, "jax_compilation_cache_dir": path,
            "jax_persistent_cache_min_compile_time_secs": 0.0 if writable else _NEVER,
            "jax_persistent_cache_min_entry_size_bytes": 0}


def _quiet_write_failures():
    # a full disk or a folder made read-only after start-up: JAX warns once per program
    warnings.filterwarnings("ignore", message="Error writing persistent compilation cache entry",
                            category=UserWarning)


def _apply(path, writable):
    if path is not None and not writable and not os.path.isdir(path):
        path = None  # cannot be created: nothing to read either
    settings = _settings(path, writable)
    _state.update(dir=path, writable=bool(path) and writable)
    if "jax" not in sys.modules:
        for key, value in settings.items():
            os.environ[key.upper()] = str(value).lower() if isinstance(value, bool) else str(value)
        return
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    for key, value in settings.items():
        jax.config.update(key, value)
    compilation_cache.reset_cache()  # the next compilation opens the new folder


def configure():
    """Turn on the default persistent cache (runs on ``import geomopt``; float64 is scoped to
    geomopt's own calls, :mod:`geomopt._runtime.x64`)."""
    with _lock:
        path = default_dir()
        _apply(path, path is not None and _writable(path))
        _quiet_write_failures()


def set_cache_dir(path):
    """Use ``path`` (str or Path) as the persistent compilation cache, or turn it off (None).

    Applies to every later compilation in this process (the CLI and the API share it); the
    programs already compiled stay in memory.  A folder that cannot be written is read only.
    Returns the folder in use (None when off).
    """
    with _lock:
        path = None if path is None else os.path.abspath(os.path.expanduser(os.fspath(path)))
        _apply(path, path is not None and _writable(path))
        return path


#: the environment variable of the cache folder's size limit in MB (default :data:`DEFAULT_MAX_MB`;
#: ``0``, ``off`` or ``none``: no limit)
MAX_ENV = "GEOMOPT_CACHE_MAX_MB"
DEFAULT_MAX_MB = 2048


def max_bytes() -> int | None:
    """The cache folder's size limit in bytes (``GEOMOPT_CACHE_MAX_MB``), None for no limit; a
    value that is not a number of MB is refused in one line."""
    value = os.environ.get(MAX_ENV, str(DEFAULT_MAX_MB)).strip().lower()
    if value in _OFF:
        return None
    try:
        mb = float(value)
    except ValueError:
        mb = math.nan
    if not mb >= 0:  # also NaN: not a number
        raise ParameterError(f"{MAX_ENV}={value!r} is not a size in MB; give a number, or off for no limit")
    return None if mb == 0 else int(mb * 2**20)


def prune(folder=None, limit=None) -> int:
    """Delete the least recently used files of the cache ``folder`` (default: the one in use;
    JAX's entries and geomopt's ``programs/``) while it holds more than 3/4 of ``limit`` bytes
    (default :func:`max_bytes`), once it holds more than ``limit``.  "Used" is a file's
    modification time: a kept program is touched each time it is loaded, JAX's entries when
    written.  Returns the number of files deleted (0 with no limit, no folder, or a folder that
    cannot be written).  Runs after geomopt compiles (and keeps) a program: a warm process never
    lists the folder."""
    folder = cache_dir() if folder is None else folder
    limit = max_bytes() if limit is None else limit
    if folder is None or limit is None:
        return 0
    files = []
    for base in (folder, os.path.join(folder, "programs")):
        with contextlib.suppress(OSError), os.scandir(base) as entries:
            for entry in entries:
                with contextlib.suppress(OSError):
                    if entry.is_file(follow_symlinks=False) and not entry.name.startswith(".probe"):
                        st = entry.stat(follow_symlinks=False)
                        files.append((st.st_mtime, st.st_size, entry.path))
    total = sum(size for _, size, _ in files)
    if total <= limit:
        return 0
    deleted = 0
    for _, size, path in sorted(files):
        if total <= 0.75 * limit:
            break
        with contextlib.suppress(OSError):
            os.remove(path)
            total -= size
            deleted += 1
    return deleted


def prune_once() -> None:
    """:func:`prune` in a background thread, once per process (the first compilation kept)."""
    with _lock:
        if _state["pruned"]:
            return
        _state["pruned"] = True
    threading.Thread(target=lambda: prune(), daemon=True).start()


def cache_dir() -> str | None:
    """The persistent compilation cache folder in use (None when off)."""
    return _state["dir"]


def programs_dir() -> str | None:
    """Where :mod:`geomopt._runtime.programs` keeps compiled programs: ``programs`` in JAX's persistent
    cache folder when that cache is on (so that Dask workers given the client's JAX settings
    share it), None when off or ``GEOMOPT_PROGRAMS`` is ``off``."""
    import jax

    if os.environ.get("GEOMOPT_PROGRAMS", "on").strip().lower() in _OFF:
        return None
    folder = jax.config.jax_compilation_cache_dir if jax.config.jax_enable_compilation_cache else None
    return os.path.join(folder, "programs") if folder else None


def programs_writable() -> bool:
    """False for geomopt's own cache folder when it is read-only; else True (a failed write
    is skipped)."""
    import jax

    ours = os.path.abspath(jax.config.jax_compilation_cache_dir or "") == os.path.abspath(_state["dir"] or "")
    return _state["writable"] or not ours


@contextlib.contextmanager
def bypassed():
    """JAX's persistent cache off inside the block (then as before): an executable loaded from
    it cannot be serialised again (XLA CPU then misses its kernels at run time: "Function ...
    not found"), so :mod:`geomopt._runtime.programs` compiles the programs it keeps afresh.  Each use
    counts as a miss in :func:`cache_stats`.  Another thread compiling meanwhile compiles
    without the cache."""
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    with _lock:
        on = jax.config.jax_enable_compilation_cache
        _state["bypassed"] += 1
        if on:
            jax.config.update("jax_enable_compilation_cache", False)
            compilation_cache.reset_cache()
        try:
            yield
        finally:
            if on:
                jax.config.update("jax_enable_compilation_cache", True)
                compilation_cache.reset_cache()


def count_loaded():
    """Count a program :mod:`geomopt._runtime.programs` loaded from its own folder as a hit (a
    persistent-cache lookup that found its program) in :func:`cache_stats`."""
    with _lock:
        _state["hits"] += 1
        _state["requests"] += 1


def _count(event, **kwargs):
    # JAX's own "cache_misses" event counts writes; a miss is a lookup that was not a hit
    if event == "/jax/compilation_cache/cache_hits":
        _state["hits"] += 1
    elif event == "/jax/compilation_cache/compile_requests_use_cache":
        _state["requests"] += 1


def cache_stats() -> dict:
    """Persistent-cache lookups in this process since the first call: ``{"dir", "writable",
    "hits", "misses"}`` (a miss compiles; with the cache off nothing is counted).  Imports JAX
    to start counting."""
    with _lock:
        if not _state["listening"]:
            import jax.monitoring

            jax.monitoring.register_event_listener(_count)
            _state["listening"] = True
        # a program compiled outside JAX's cache for geomopt._runtime.programs is a miss too
        return {"dir": _state["dir"], "writable": _state["writable"], "hits": _state["hits"],
                "misses": _state["requests"] - _state["hits"] + _state["bypassed"]}
