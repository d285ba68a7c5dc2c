"""Run every benchmark in bench/ (``bench_*.py`` with a ``main()``).

Figures go to build/bench/*.json.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    here = Path(__file__).resolve().parent
    names = argv or sorted(p.stem for p in here.glob("bench_*.py"))
    status = 0
    for name in names:
        path = here / f"{name}.py"
        if not path.exists():
            print(f"no benchmark {name!r} in {here}", file=sys.stderr)
            return 2
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        print(f"== {name}", flush=True)
        # each benchmark parses its own options; run it with its defaults
        saved, sys.argv = sys.argv, [str(path)]
        try:
            status |= int(mod.main() or 0)
        finally:
            sys.argv = saved
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
