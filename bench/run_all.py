"""Run every benchmark in this folder, one after the other (``make bench``).

A benchmark that ends with ``sys.exit(code)`` ends only itself: the next one runs, and the
exit status is that of the last benchmark that failed (0 when none did), with a line naming
each failure at the end.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path


def main() -> int:
    here = Path(__file__).resolve().parent
    failed = []
    for script in sorted(here.glob("*.py")):
        if script.name == "run_all.py" or script.name.startswith("_"):
            continue
        print(f"=== {script.name}", flush=True)
        sys.argv = [str(script)]
        try:
            runpy.run_path(str(script), run_name="__main__")
        except SystemExit as done:  # sys.exit(main()) in the benchmark: go on to the next
            code = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
            if code:
                failed.append((script.name, code))
    for name, code in failed:
        print(f"run_all: {name} exited with {code}", file=sys.stderr)
    return failed[-1][1] if failed else 0


if __name__ == "__main__":
    sys.exit(main())
