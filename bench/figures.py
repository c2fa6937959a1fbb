"""``python -m bench.figures``: regenerate the documentation's figures from run directories.

    python -m bench.figures                       # every figure of docs/figures/manifest.toml
    python -m bench.figures --only curves_pendulum policy_pendulum
    python -m bench.figures RUN_DIR [RUN_DIR ...] # learning curves of these runs, one per env
    make figures

The manifest maps each figure to what it is drawn from, so that the figures can be redrawn
whenever the runs are redone; nothing is drawn by hand. Four kinds (``[kind.name]`` tables):

* ``curves.NAME`` -> ``curves_NAME.png``: for one env, each run's mean eval return over seeds
  with its 95% bootstrap band, against the published reference curves of that env
  (``bench/reference_curves/*.json``; ``reference = [...]`` chooses, default all that cover it).
  Keys: ``runs``, optional ``labels``, ``title``, ``reference``, ``max_step``, ``line =
  [value, "label"]``, ``legend`` (matplotlib's ``loc``, or ``"below"`` the axes; default
  ``"best"``).
* ``aggregate.NAME`` -> ``aggregate_NAME.png``: over a suite of envs, each learner's IQM of
  normalised final scores and its performance profile, with stratified-bootstrap 95% intervals
  (``bench/figure_stats.py``). The scores come from ``runs`` (run directories; optional
  ``labels``: runs with one label pool as one learner) or from ``rows`` = ``{label: [ROW,
  ...]}``, RESULTS.md's rows by name (their per-seed final returns, as ``python -m
  bench.results ROW`` wrote them), which must cover the same envs for every label. Keys: one of
  those, optional ``title``, and ``normalize.<env id>`` = ``{low, high}``, ``{high, source}``
  (a published number, ``source`` saying whose) or ``{reference, step, low}`` (``high``: the
  reference curves' mean return at ``step``); ``low`` defaults to 0.
* ``speed.NAME`` -> ``speed_NAME.png``: bars of a benchmark table (``source`` file, the first
  table after the heading containing ``heading``), one group per row (``label`` columns), one
  bar per ``bars`` column, ratios over ``baseline``. Optional ``names``, ``title``, ``unit``,
  ``log``.
* ``gifs.NAME`` -> ``policy_NAME.gif``: the best seed's best policy of ``run`` (``seed`` to
  choose; ``latest = true``: its latest checkpoint's policy instead), rendered by
  ``rl_jax.run.render``: ``episodes`` episodes (default 1), or, for a board-game run, that many
  games against the run's evaluation opponent.

Any entry may have a ``caption``: what the documentation site writes under the image (default:
its ``title``; ``docs/_ext/rl_jax_docs.py`` reads it).

Paths are relative to the repository root. A figure whose run directory (or results file) is
missing is skipped with one line saying so; the others are still made. Every image is written at
most 150 KB.
"""

from __future__ import annotations

import sys
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import figure_plots, figure_stats
from bench.figure_data import (
    ROOT,
    FigureError,
    cell_number,
    final_scores,
    markdown_table,
    read_reference,
    read_run,
    reference_names,
    resolve,
    result_rows,
    table_columns,
)
from rl_jax.errors import OneLineParser

MANIFEST = ROOT / "docs" / "figures" / "manifest.toml"
OUT = ROOT / "docs" / "figures"

#: Per kind: the file name's prefix and suffix, and the keys an entry may have (the first
#: ones are required).
KINDS: dict[str, tuple[str, str, tuple[str, ...], tuple[str, ...]]] = {
    "curves": (
        "curves_",
        ".png",
        ("runs",),
        ("labels", "title", "reference", "max_step", "line", "legend", "caption"),
    ),
    "aggregate": (
        "aggregate_",
        ".png",
        ("normalize",),
        ("runs", "rows", "labels", "title", "caption"),
    ),
    "speed": (
        "speed_",
        ".png",
        ("source", "heading", "label", "bars"),
        ("names", "baseline", "title", "unit", "log", "caption"),
    ),
    "gifs": ("policy_", ".gif", ("run",), ("seed", "max_frames", "episodes", "caption", "latest")),
}


class ManifestError(Exception):
    """The manifest itself is wrong: the command stops with one line."""


def file_name(kind: str, name: str) -> str:
    """The image a manifest entry makes: ``curves_NAME.png``, ``policy_NAME.gif``, ..."""
    prefix, suffix, _, _ = KINDS[kind]
    return f"{prefix}{name}{suffix}"


def read_manifest(path: Path) -> dict[str, dict[str, dict[str, Any]]]:
    """The manifest's figures by kind, each entry's keys checked."""
    try:
        manifest = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ManifestError(f"no manifest at {path}") from None
    except (OSError, tomllib.TOMLDecodeError) as error:
        raise ManifestError(f"{path} is not readable TOML: {error}") from None
    for kind, entries in manifest.items():
        if kind not in KINDS:
            raise ManifestError(f"{path}: unknown figure kind [{kind}]; use one of {list(KINDS)}")
        _, _, required, optional = KINDS[kind]
        for name, entry in entries.items():
            missing = [key for key in required if key not in entry]
            unknown = sorted(set(entry) - set(required) - set(optional))
            if missing or unknown:
                problem = f"lacks {missing}" if missing else f"has unknown keys {unknown}"
                raise ManifestError(f"{path}: [{kind}.{name}] {problem}")
            runs = entry.get("runs", [])
            if not isinstance(runs, list) or not all(isinstance(run, str) for run in runs):
                raise ManifestError(f"{path}: [{kind}.{name}] runs must be a list of paths")
    return manifest


# ---- one figure per kind ------------------------------------------------------------------


def _runs(entry: dict[str, Any]) -> tuple[list[Any], str]:
    """The entry's runs that exist, and a note naming those left out because they are missing
    (all missing: ``FigureError``, and the figure is skipped)."""
    if not entry["runs"] or isinstance(entry["runs"], str):
        raise FigureError("its runs must be a non-empty list of run directories")
    labels = entry.get("labels") or [None] * len(entry["runs"])
    if len(labels) != len(entry["runs"]):
        raise FigureError(f"{len(labels)} labels for {len(entry['runs'])} runs")
    runs, missing = [], []
    for run_dir, label in zip(entry["runs"], labels, strict=True):
        if not resolve(run_dir).is_dir():
            missing.append(str(run_dir))
            continue
        runs.append(read_run(run_dir, label))
    if not runs:
        listed = "run directory" if len(missing) == 1 else "run directories"
        raise FigureError(
            f"{listed} {', '.join(missing)} {'is' if len(missing) == 1 else 'are'} missing"
        )
    return runs, (f" (left out, missing: {', '.join(missing)})" if missing else "")


def make_curves(entry: dict[str, Any], path: Path) -> str:
    """A learning-curve figure of one env; a note on what it holds."""
    runs, left_out = _runs(entry)
    env_ids = sorted({run.env_id for run in runs})
    if len(env_ids) != 1:
        raise FigureError(f"its runs are on different envs: {env_ids}")
    env_id = env_ids[0]
    names = entry.get("reference")
    if names is None:
        names = [name for name in reference_names() if _covers(name, env_id)]
    references = [
        read_reference(name, env_id) for name in ([names] if isinstance(names, str) else names)
    ]
    line = entry.get("line")
    size = figure_plots.curves_figure(
        runs,
        references,
        path,
        entry.get("title", env_id),
        entry.get("max_step"),
        (float(line[0]), str(line[1])) if line else None,
        str(entry.get("legend", "best")),
    )
    against = f" against {', '.join(r.name for r in references)}" if references else ""
    return f"{len(runs)} runs on {env_id}{against}, {size / 1024:.0f} KB{left_out}"


def _covers(reference: str, env_id: str) -> bool:
    try:
        read_reference(reference, env_id)
    except FigureError:
        return False
    return True


def _scale(env_id: str, spec: dict[str, Any]) -> tuple[float, float, str]:
    """``(low, high, description)`` of an env's normalisation."""
    low = float(spec.get("low", 0.0))
    if "reference" in spec:
        reference = read_reference(str(spec["reference"]), env_id)
        step = int(spec.get("step", reference.steps[-1]))
        high = reference.mean_at(step)
        return low, high, f"{env_id}: {reference.name}'s mean at {step:,} steps"
    if "high" not in spec:
        raise FigureError(f"normalize.{env_id} needs high, or reference (and step)")
    if "source" in spec:
        return low, float(spec["high"]), f"{env_id}: {float(spec['high']):,g} ({spec['source']})"
    return low, float(spec["high"]), f"{env_id}: [{low:g}, {float(spec['high']):g}]"


def _run_finals(entry: dict[str, Any]) -> tuple[dict[str, dict[str, list[Any]]], str]:
    """Each learner's final scores per env, from the entry's run directories."""
    runs, left_out = _runs(entry)
    finals: dict[str, dict[str, list[Any]]] = {}
    for run in runs:
        label = run.label if entry.get("labels") else run.algorithm.upper()
        finals.setdefault(label, {}).setdefault(run.env_id, []).append(final_scores(run))
    return finals, left_out


def _row_finals(entry: dict[str, Any]) -> tuple[dict[str, dict[str, list[Any]]], str]:
    """Each learner's final scores per env, from RESULTS.md's rows named by the entry; every
    learner on the same envs, so that the aggregate compares like with like."""
    rows, named = result_rows(), entry["rows"]
    if not isinstance(named, dict) or not named:
        raise FigureError("its rows must be a table of label = [RESULTS.md row names]")
    finals: dict[str, dict[str, list[Any]]] = {}
    for label, names in named.items():
        for name in names:
            if name not in rows:
                raise FigureError(f"RESULTS.md has no row {name!r}")
            row = rows[name]
            finals.setdefault(label, {}).setdefault(row.env_id, []).append(row.finals)
    envs = {label: sorted(by_env) for label, by_env in finals.items()}
    first = next(iter(envs.values()))
    for label, theirs in envs.items():
        if theirs != first:
            raise FigureError(f"{label}'s rows cover {theirs}, not the same envs as {first}")
    return finals, ""


def make_aggregate(entry: dict[str, Any], path: Path) -> str:
    """The IQM and performance-profile figure over a suite; a note with the IQMs."""
    if ("runs" in entry) == ("rows" in entry):
        raise FigureError("give runs (run directories) or rows (RESULTS.md's rows), one of them")
    finals, left_out = _row_finals(entry) if "rows" in entry else _run_finals(entry)
    scales = {}
    for env_id in sorted({env for by_env in finals.values() for env in by_env}):
        if env_id not in entry["normalize"]:
            raise FigureError(f"no normalize entry for {env_id}")
        scales[env_id] = _scale(env_id, entry["normalize"][env_id])
    scores: dict[str, list[Any]] = {}
    for label, by_env in finals.items():
        for env_id, per_env in by_env.items():
            low, high, _ = scales[env_id]
            scores.setdefault(label, []).extend(
                figure_stats.normalize(values, low, high) for values in per_env
            )
    if all("source" in entry["normalize"][env] for env in scales):
        normalised = "final return / reference, per env"
    else:
        normalised = "0 at low, 1 at high per env" if len(scales) > 1 else "0 at low, 1 at high"
    size, iqms = figure_plots.aggregate_figure(
        scores, path, entry.get("title", "suite aggregate"), normalised
    )
    values = ", ".join(
        f"{label} IQM {c:.2f} [{lo:.2f}, {hi:.2f}]" for label, (c, lo, hi) in iqms.items()
    )
    scale_notes = "; ".join(s[2] for s in scales.values())
    return f"{values}; scales: {scale_notes}, {size / 1024:.0f} KB{left_out}"


def make_speed(entry: dict[str, Any], path: Path) -> str:
    """A bar chart of a benchmark table; a note on its size."""
    rows = markdown_table(entry["source"], entry["heading"])
    label_columns = [entry["label"]] if isinstance(entry["label"], str) else entry["label"]
    baseline = entry.get("baseline")
    table_columns(rows, [*label_columns, *entry["bars"]], entry["source"])
    names = entry.get("names") or entry["bars"]
    if len(names) != len(entry["bars"]):
        raise FigureError(f"{len(names)} names for {len(entry['bars'])} bars")
    labels = [" ".join(row[c] for c in label_columns) for row in rows]
    series = {
        n: [cell_number(row[c]) for row in rows] for n, c in zip(names, entry["bars"], strict=True)
    }
    if baseline is not None and baseline not in entry["bars"]:
        raise FigureError(f"baseline {baseline!r} is not one of its bars")
    base_name = names[entry["bars"].index(baseline)] if baseline else None
    title = entry.get("title", entry["heading"])
    size = figure_plots.speed_figure(
        labels, series, base_name, path, title, entry.get("unit", ""), bool(entry.get("log"))
    )
    return f"{len(rows)} rows x {len(series)} bars from {entry['source']}, {size / 1024:.0f} KB"


def make_gif(entry: dict[str, Any], path: Path) -> str:
    """A GIF of a run's best policy, at most 150 KB; a note on its size."""
    from rl_jax.errors import user_errors
    from rl_jax.run.render import write_gif
    from rl_jax.training.jax_setup import configure

    run_dir = resolve(entry["run"])
    if not run_dir.is_dir():
        raise FigureError(f"run directory {entry['run']} is missing")
    configure()
    with tempfile.TemporaryDirectory() as scratch:
        full = Path(scratch) / "policy.gif"
        try:
            write_gif(
                run_dir,
                entry.get("seed"),
                int(entry.get("episodes", 1)),
                full,
                max_frames=int(entry.get("max_frames", 300)),
                which="latest" if entry.get("latest") else "best",
            )
        except user_errors() as error:
            raise FigureError(" ".join(str(error).split())) from None
        size = figure_plots.shrink_gif(full, path)
    return f"{size / 1024:.0f} KB"


MAKERS: dict[str, Callable[[dict[str, Any], Path], str]] = {
    "curves": make_curves,
    "aggregate": make_aggregate,
    "speed": make_speed,
    "gifs": make_gif,
}


# ---- the command ----------------------------------------------------------------------------


def from_run_dirs(run_dirs: list[Path]) -> dict[str, dict[str, dict[str, Any]]]:
    """A manifest of learning curves for run directories given on the command line: one
    figure per env, named after the env (``curves_HalfCheetah-v5.png``)."""
    by_env: dict[str, list[str]] = {}
    for run_dir in run_dirs:
        try:
            env_id = read_run(run_dir).env_id
        except FigureError as error:
            print(f"skipped {run_dir}: {error}")
            continue
        by_env.setdefault(env_id, []).append(str(run_dir))
    return {"curves": {env.split("/")[-1]: {"runs": runs} for env, runs in by_env.items()}}


def make_all(
    manifest: dict[str, dict[str, dict[str, Any]]], out: Path, only: list[str] | None = None
) -> tuple[list[Path], list[str]]:
    """Make every figure of ``manifest`` (those named in ``only``) into ``out``: the images
    written, and one line per figure skipped."""
    out.mkdir(parents=True, exist_ok=True)
    written, skipped = [], []
    for kind, entries in manifest.items():
        for name, entry in entries.items():
            target = file_name(kind, name)
            if only and target not in only and Path(target).stem not in only:
                continue
            try:
                note = MAKERS[kind](entry, out / target)
            except (FigureError, OSError) as error:  # a bug elsewhere shows its traceback
                reason = error if isinstance(error, FigureError) else _unreadable(error)
                skipped.append(f"skipped {target}: {reason}")
                print(skipped[-1], flush=True)
                continue
            written.append(out / target)
            print(f"wrote {_shown(out / target)}: {note}", flush=True)
    return written, skipped


def _unreadable(error: OSError) -> str:
    return f"cannot read or write {error.filename or ''}: {error.strerror or error}"


def _shown(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def main(argv: list[str] | None = None) -> int:
    """The command: make the figures; 0, or 2 after one line on a bad manifest or flag."""
    parser = OneLineParser(prog="python -m bench.figures", description=__doc__.split("\n")[0])
    parser.add_argument("run_dirs", nargs="*", type=Path, help="runs to plot (default: manifest)")
    parser.add_argument("--manifest", type=Path, default=MANIFEST, help="figures -> sources")
    parser.add_argument("--out", type=Path, default=OUT, help="where images go (docs/figures)")
    parser.add_argument("--only", nargs="+", help="figures to make, by file name or stem")
    args = parser.parse_args(argv)
    try:
        manifest = from_run_dirs(args.run_dirs) if args.run_dirs else read_manifest(args.manifest)
    except ManifestError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    known = [file_name(kind, name) for kind, entries in manifest.items() for name in entries]
    unknown = [
        n for n in args.only or [] if n not in known and n not in [Path(k).stem for k in known]
    ]
    if unknown:
        print(
            f"error: no figure {unknown[0]!r} in {args.manifest}; it has {known}", file=sys.stderr
        )
        return 2
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        print(
            f"error: cannot write to --out {args.out}: {error.strerror or error}", file=sys.stderr
        )
        return 2
    written, skipped = make_all(manifest, args.out, args.only)
    print(f"{len(written)} figures written to {_shown(args.out)}, {len(skipped)} skipped")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(argv=None))
