"""``python -m bench [NAME ...] [--quick]`` runs the benchmarks and prints their tables.

Each benchmark is a module ``bench/bench_<name>.py`` with ``run(quick: bool) -> str`` returning a
Markdown section (machine line, command, table with ratios). Results are also written to
``bench/results/<name>.md`` so BENCHMARKS.md can be updated from them.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from pathlib import Path

import bench

RESULTS = Path(__file__).resolve().parent / "results"


def available() -> list[str]:
    names = [m.name for m in pkgutil.iter_modules(bench.__path__) if m.name.startswith("bench_")]
    return sorted(n.removeprefix("bench_") for n in names)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("names", nargs="*", help=f"benchmarks to run (default all): {available()}")
    parser.add_argument("--quick", action="store_true", help="smaller sizes, for a smoke run")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.names) - set(available()))
    if unknown:
        print(f"error: unknown benchmark(s) {unknown}; available: {available()}", file=sys.stderr)
        return 2
    from rl_jax.training.jax_setup import configure

    configure()
    RESULTS.mkdir(exist_ok=True)
    for name in args.names or available():
        module = importlib.import_module(f"bench.bench_{name}")
        section = module.run(quick=args.quick)
        print(section, flush=True)
        (RESULTS / f"{name}.md").write_text(section)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
