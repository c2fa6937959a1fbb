"""The type check of `make typecheck` and CI: mypy over rl_jax/ and its env package rl_jax.envs
(its settings are in pyproject.toml), held to a baseline that may only shrink.

scripts/typecheck_baseline.txt lists the errors the code had when the list was last written, one
per line as "path: [code] message" (no line numbers, so that an edit elsewhere in the file does
not touch the list). The check fails when mypy finds more errors than the list holds, naming the
ones the list lacks, and when it finds fewer, asking for the list to be written again:

    python scripts/typecheck.py            # the check
    python scripts/typecheck.py --update   # rewrite the list; refused if it would grow

A new mypy release (`make lock`) may find more errors in unchanged code: then
`--update --allow-growth`, and say why in the commit.
"""

from __future__ import annotations

import argparse
import collections
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BASELINE = ROOT / "scripts" / "typecheck_baseline.txt"
HEADER = """\
# mypy errors in rl_jax/ and rl_jax/envs (scripts/typecheck.py): this list may only shrink.
# One line per error, "path: [code] message", sorted; regenerate with
# `python scripts/typecheck.py --update`.
"""
# "path:line: error: message  [code]", as mypy prints it with its default settings
ERROR = re.compile(
    r"^(?P<path>[^:\s]+):\d+(?::\d+)?: error: (?P<message>.*?)  \[(?P<code>[a-z-]+)\]$"
)


def run_mypy() -> dict[str, list[str]]:
    """The errors mypy reports: each as its baseline line -> mypy's lines for it (with line
    numbers; an error that occurs several times in a file has several)."""
    command = [
        sys.executable,
        "-m",
        "mypy",
        "--no-pretty",
        "--no-color-output",
        "--no-error-summary",
    ]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False)
    output = done.stdout + done.stderr
    if done.returncode not in (0, 1):  # 2: mypy itself failed (bad settings, a crash)
        sys.exit(f"mypy failed (exit {done.returncode}):\n{output}")
    errors: dict[str, list[str]] = collections.defaultdict(list)
    for line in output.splitlines():
        if match := ERROR.match(line):
            errors[f"{match['path']}: [{match['code']}] {match['message']}"].append(line)
    return errors


def read_baseline() -> list[str]:
    lines = BASELINE.read_text().splitlines() if BASELINE.exists() else []
    return [line for line in lines if line and not line.startswith("#")]


def write_baseline(errors: list[str]) -> None:
    BASELINE.write_text(HEADER + "".join(f"{error}\n" for error in errors))


def main(argv: list[str] | None = None) -> int:
    """Run the check (or, with --update, rewrite the baseline); return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--update", action="store_true", help="rewrite the baseline list")
    parser.add_argument(
        "--allow-growth", action="store_true", help="with --update: also when it grows"
    )
    args = parser.parse_args(argv)
    start = time.perf_counter()
    found = run_mypy()
    seconds = time.perf_counter() - start
    errors = sorted(error for error, lines in found.items() for _ in lines)
    baseline = read_baseline()
    print(f"mypy: {len(errors)} errors, baseline {len(baseline)} ({seconds:.1f} s)")
    if args.update:
        if len(errors) > len(baseline) and not args.allow_growth:
            print(f"refused: the baseline may only shrink ({len(baseline)} -> {len(errors)})")
            return 1
        write_baseline(errors)
        print(f"wrote {BASELINE.relative_to(ROOT)}")
        return 0
    if len(errors) > len(baseline):
        new = collections.Counter(errors) - collections.Counter(baseline)
        print(f"{len(errors) - len(baseline)} more type errors than the baseline; not in it:")
        for error in sorted(new):
            print("".join(f"  {line}\n" for line in found[error]), end="")
        return 1
    if len(errors) < len(baseline):
        print(
            f"{len(baseline) - len(errors)} fewer type errors than the baseline: lower it with "
            "`python scripts/typecheck.py --update` and commit the list"
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
