"""Command line: geomopt param, geomopt untangle, geomopt smooth, geomopt fair, geomopt compare, geomopt demo.

Every failure on bad input (unreadable or invalid mesh, unknown name, invalid value, output
that cannot be written, a command line argparse refuses) prints one line ``geomopt: error:
...`` and exits with status 2 (no traceback and no NumPy warning unless ``--debug``; with
``--json`` the JSON summary is printed too); a solve that does not end converged and flip-free (exact
predicate) exits with status 1 and writes nothing; status 0 means the certified result was
written.  Every output path (derived ones included) is checked before the input is read, by
:func:`geomopt.io.check_outputs`: it must be a regular file or not exist, and no output may be an
input (a command creates or replaces nothing but its named outputs; an output folder is created,
never its parents).  Outputs are written atomically, all of them or none; an
interrupt (SIGINT, SIGTERM, SIGHUP) removes the unfinished temporary files and exits with
status 128 + the signal number (a batch first writes the summary of what finished).
``compare`` writes all its files and exits 0 only when every solver converged certified, else 1.

The modules: :mod:`~geomopt.cli.run` (the process: :func:`main`, :func:`entry`, signals, warnings, the
JSON summary, exit statuses), :mod:`~geomopt.cli.parser` (the argparse grammar), :mod:`~geomopt.cli.common` (what
every command shares), and one per command: :mod:`~geomopt.cli.param` (with :mod:`~geomopt.cli.atlas`; ``demo``),
:mod:`~geomopt.cli.untangle`, :mod:`~geomopt.cli.smooth`, :mod:`~geomopt.cli.fair`, :mod:`~geomopt.cli.compare`.  They parse, call the library and print.
"""

from __future__ import annotations

from .._runtime.formats import PICTURE_EXTENSIONS
from .common import EXIT_EXCEPT_FIXED, EXIT_FAILED, EXIT_OK, EXIT_USAGE
from .compare import cmd_compare
from .fair import cmd_fair
from .param import cmd_demo, cmd_param
from .parser import build_parser
from .run import entry, main
from .smooth import cmd_smooth
from .untangle import cmd_untangle

__all__ = [
    "main", "entry", "build_parser", "cmd_param", "cmd_untangle", "cmd_smooth", "cmd_fair", "cmd_compare", "cmd_demo", "EXIT_OK",
    "EXIT_FAILED", "EXIT_USAGE", "EXIT_EXCEPT_FIXED", "PICTURE_EXTENSIONS",
]
