"""Where a warm ``geomopt demo`` spends its time drawing, beside its solve.

Runs ``geomopt demo -o OUT --json`` in this process (run it twice: the second run is the warm
one, its compiled programs loaded from the persistent cache) and prints one JSON line: the
demo's own ``timing`` split (its ``figures`` phase: the checkerboard figure and the convergence
figure, drawn, PNG-encoded and written), the ratios ``figures / solve`` and ``total / solve``,
and the load average.  Targets (DESIGN.md section 3): figures <= 0.5 solve, total <= 2.5 solve.

    python benchmarks/figures.py /tmp/demo_out      # run twice, read the second line
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys


def main(out):
    from geomopt import cli

    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.suppress(SystemExit):
        cli.main(["demo", "-o", out, "--json", "--quiet"])
    split = json.loads(stdout.getvalue().strip().splitlines()[-1])["timing"]
    row = {"load": round(os.getloadavg()[0], 2), **split}
    row["figures/solve"] = round(split["figures"] / split["solve"], 3)
    row["total/solve"] = round(split["total"] / split["solve"], 3)
    print(json.dumps(row))

if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out")
