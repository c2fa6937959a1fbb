"""What the figures are drawn from: run directories (``config.json`` and ``metrics.jsonl``), the
published reference curves under ``bench/reference_curves/``, the Markdown tables of the
benchmark results, and the per-seed final returns of RESULTS.md's rows.

Everything here reads; nothing writes. Problems are ``FigureError``s with one line of text, which
``bench.figures`` prints before skipping the figure concerned.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from rl_jax.errors import RunError
from rl_jax.run.metrics import METRICS_FILE, read_rows
from rl_jax.run.plots import curves_from_rows
from rl_jax.run.run_dir import read_run_record

ROOT = Path(__file__).resolve().parent.parent
REFERENCES = Path(__file__).resolve().parent / "reference_curves"


class FigureError(Exception):
    """A figure cannot be made from what it names (a missing run, an unknown reference)."""


@dataclasses.dataclass
class RunCurves:
    """One learner's eval returns in one run: ``returns[seed, eval]`` at ``steps[eval]``."""

    label: str
    algorithm: str
    env_id: str
    steps: np.ndarray  # [T] int
    returns: np.ndarray  # [S, T] float, NaN where a seed has no eval


def resolve(path: str | Path) -> Path:
    """A manifest path: absolute as given, relative from the repository root."""
    path = Path(path).expanduser()
    return path if path.is_absolute() else ROOT / path


def read_run(run_dir: str | Path, label: str | None = None, config: int = 0) -> RunCurves:
    """The eval curve of one config (default the first) of a run directory."""
    directory = resolve(run_dir)
    if not directory.is_dir():
        raise FigureError(f"run directory {run_dir} is missing")
    try:
        record = read_run_record(directory)
    except RunError as error:
        raise FigureError(str(error)) from None
    identity = record["identity"]
    curves = curves_from_rows(read_rows(directory / METRICS_FILE))
    if not curves:
        raise FigureError(f"{run_dir} has no evaluations yet ({METRICS_FILE} is empty)")
    if config >= len(curves):
        raise FigureError(f"{run_dir} has {len(curves)} configs, not config {config}")
    curve = curves[config]
    algorithm = str(identity.get("algorithm", "?"))
    label = label or f"{algorithm.upper()} ({len(curve.seeds)} seeds)"
    return RunCurves(label, algorithm, str(identity["env_id"]), curve.steps, curve.returns)


def final_scores(run: RunCurves, step: int | None = None) -> np.ndarray:
    """Each seed's eval return at ``step`` (default: the run's last eval): ``[S]``."""
    if step is None:
        index = len(run.steps) - 1
    else:
        matches = np.flatnonzero(run.steps == step)
        if matches.size == 0:
            raise FigureError(f"{run.label} on {run.env_id} has no eval at step {step:,}")
        index = int(matches[0])
    scores = run.returns[:, index]
    return scores[np.isfinite(scores)]


# ---- reference curves ---------------------------------------------------------------------


@dataclasses.dataclass
class Reference:
    """A published learner's per-seed curves on one env, with where they come from."""

    name: str
    env_id: str
    source_env: str
    steps: np.ndarray  # [T]
    returns: np.ndarray  # [S, T]

    @property
    def label(self) -> str:
        """The legend's text: name, seed count and the env it was measured on."""
        return f"{self.name} ({self.returns.shape[0]} seeds, {self.source_env})"

    def returns_at(self, step: int) -> np.ndarray:
        """Each seed's return ``[n]`` at the reference's eval nearest ``step``."""
        return self.returns[:, int(np.argmin(np.abs(self.steps - step)))]

    def mean_at(self, step: int) -> float:
        """The mean over seeds at the reference's eval nearest ``step``."""
        return float(np.mean(self.returns_at(step)))


def reference_names() -> list[str]:
    """The reference files available (their names without ``.json``)."""
    return sorted(path.stem for path in REFERENCES.glob("*.json"))


def read_reference(name: str, env_id: str) -> Reference:
    """The curves of reference ``name`` (``bench/reference_curves/<name>.json``) on ``env_id``."""
    path = REFERENCES / f"{name}.json"
    if not path.is_file():
        raise FigureError(f"unknown reference {name!r}; available: {reference_names()}")
    data = json.loads(path.read_text())
    entry = data["envs"].get(env_id)
    if entry is None:
        raise FigureError(f"reference {name!r} has no curves for {env_id}")
    returns = np.asarray(entry["returns"], np.float64)
    steps = np.asarray(entry.get("steps", data["steps"]), np.int64)
    return Reference(str(data["name"]), env_id, str(entry["gym_id"]), steps, returns)


# ---- Markdown tables ------------------------------------------------------------------------

#: A number as the tables write it: thousands separated by commas ("1,029,909"), or a decimal.
_NUMBER = re.compile(r"-?\d{1,3}(?:,\d{3})+(?:\.\d+)?|-?\d+(?:\.\d+)?")


def cell_number(cell: str) -> float | None:
    """The last number of a table cell ("296, 294" -> 294, "**1.21x**" -> 1.21); None if the
    cell holds none ("skipped (compile > 180 s)" holds 180, so a cell that starts with a word
    other than a number counts as no number)."""
    text = cell.replace("*", "").strip()
    if not text or not (text[0].isdigit() or text[0] == "-"):
        return None
    numbers = _NUMBER.findall(text)
    return float(numbers[-1].replace(",", "")) if numbers else None


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def markdown_table(path: str | Path, heading: str) -> list[dict[str, str]]:
    """The first table after the first heading line containing ``heading``: one dict per row,
    keyed by the header's cells."""
    source = resolve(path)
    if not source.is_file():
        raise FigureError(f"benchmark results file {path} is missing")
    lines = source.read_text().splitlines()
    start = next(
        (i for i, line in enumerate(lines) if line.startswith("#") and heading in line), None
    )
    if start is None:
        raise FigureError(f"{path} has no heading containing {heading!r}")
    first = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("|")), None)
    if first is None:
        raise FigureError(f"{path} has no table after the heading {heading!r}")
    header = _cells(lines[first])
    rows = []
    for line in lines[first + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(header, _cells(line), strict=False)))
    return rows


def table_columns(rows: list[dict[str, str]], wanted: list[str], path: Any) -> None:
    """``FigureError`` naming the first of ``wanted`` that the table's header lacks."""
    header = list(rows[0]) if rows else []
    for column in wanted:
        if column not in header:
            raise FigureError(f"the table in {path} has no column {column!r}; it has {header}")


# ---- RESULTS.md's rows ----------------------------------------------------------------------

#: Where every row of RESULTS.md is written, one line each, by ``python -m bench.results ROW``.
RESULTS_FILE = "RESULTS.md"
RESULTS_HEADING = "Every row, as generated"
_ROW = re.compile(r"python -m bench\.results ([\w.-]+)")
_ENV_ID = re.compile(r"`([\w./-]+-v\d+)`")
#: A seed's final return, or several seeds' equal ones: "9,353", "500 (x8)".
_SEED = re.compile(r"(-?[\d,]+(?:\.\d+)?)(?: \(x(\d+)\))?")


@dataclasses.dataclass
class ResultRow:
    """One row of RESULTS.md: its name, env, budget and each seed's final eval return."""

    name: str
    env_id: str
    total_steps: int
    finals: np.ndarray  # [S]


def _finals(cell: str, name: str) -> np.ndarray:
    """``"5,019 / 5,992 / 500 (x8); mean ..."`` -> each seed's final return."""
    finals: list[float] = []
    for part in cell.split(";")[0].split(" / "):
        match = _SEED.fullmatch(part.strip())
        if match is None:
            raise FigureError(f"row {name}: cannot read a seed's final return from {part!r}")
        finals += [float(match.group(1).replace(",", ""))] * int(match.group(2) or 1)
    return np.asarray(finals, np.float64)


def result_rows(path: str | Path = RESULTS_FILE) -> dict[str, ResultRow]:
    """Every row of the results table (``## Every row, as generated``) by its name."""
    table = markdown_table(path, RESULTS_HEADING)
    columns = list(table[0]) if table else []
    final = next((c for c in columns if c.startswith("final eval return per seed")), None)
    table_columns(table, ["algorithm, env", "command", "env steps per seed"], path)
    if final is None:
        raise FigureError(f"the table in {path} has no column 'final eval return per seed'")
    rows = {}
    for cells in table:
        name, env = _ROW.search(cells["command"]), _ENV_ID.search(cells["algorithm, env"])
        steps = cell_number(cells["env steps per seed"])
        if name is None or env is None or steps is None:
            continue
        finals = _finals(cells[final], name.group(1))
        rows[name.group(1)] = ResultRow(name.group(1), env.group(1), int(steps), finals)
    return rows
