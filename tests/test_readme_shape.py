"""The front pages stay readable: README.md fits about one screen, no Markdown table cell of
README.md, RESULTS.md, BENCHMARKS.md or a docs page is an essay, and every relative link of those
pages (and of the docs pages) points at a file and a heading that exist."""

import re
from pathlib import Path

import pytest

from bench import results

ROOT = Path(__file__).resolve().parent.parent
FRONT_PAGES = ["README.md", "RESULTS.md", "BENCHMARKS.md"]
DOCS_PAGES = sorted(
    str(page.relative_to(ROOT))
    for page in (ROOT / "docs").rglob("*.md")
    if "_build" not in page.relative_to(ROOT).parts
)
MAX_README_LINES = 200
MAX_CELL = 200
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _outside_code(text: str) -> list[tuple[int, str]]:
    """The lines outside fenced code blocks, with their 1-based line numbers."""
    lines, fenced = [], False
    for number, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced:
            lines.append((number, line))
    return lines


def table_cells(text: str) -> list[tuple[int, str]]:
    """Every cell of every Markdown table row (a line starting with "|"), with its line."""
    cells = []
    for number, line in _outside_code(text):
        if line.startswith("|"):
            parts = re.split(r"(?<!\\)\|", line.strip())[1:-1]
            cells.extend((number, cell.strip()) for cell in parts)
    return cells


def heading_anchors(text: str) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces as
    hyphens, and "-1", "-2", ... after a repeated one."""
    anchors: set[str] = set()
    seen: dict[str, int] = {}
    for _, line in _outside_code(text):
        match = re.match(r"#{1,6} (.*)", line)
        if match:
            base = re.sub(r"[^\w\- ]", "", match.group(1).strip().lower()).replace(" ", "-")
            count = seen.get(base, 0)
            seen[base] = count + 1
            anchors.add(base if count == 0 else f"{base}-{count}")
    return anchors


def broken_links(page: Path) -> list[str]:
    """The relative links of ``page`` whose file, or heading in a Markdown file, is missing."""
    broken = []
    for _, line in _outside_code(page.read_text()):
        for target in LINK.findall(line):
            if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
                continue
            path_part, _, anchor = target.partition("#")
            file = (page.parent / path_part).resolve() if path_part else page
            if not file.exists():
                broken.append(f"{page.name}: {target} (no such file)")
                continue
            headings = heading_anchors(file.read_text()) if file.suffix == ".md" else set()
            if anchor and file.suffix == ".md" and anchor not in headings:
                broken.append(f"{page.name}: {target} (no such heading)")
    return broken


def test_the_readme_fits_about_one_screen():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines"


@pytest.mark.parametrize("name", FRONT_PAGES + DOCS_PAGES)
def test_no_table_cell_is_an_essay(name):
    long_cells = [
        f"{name}:{line}: {len(cell)} characters: {cell[:60]}..."
        for line, cell in table_cells((ROOT / name).read_text())
        if len(cell) > MAX_CELL
    ]
    assert not long_cells, "\n".join(long_cells)


@pytest.mark.parametrize("name", FRONT_PAGES)
def test_every_relative_link_of_the_front_pages_resolves(name):
    assert not broken_links(ROOT / name)


def test_every_relative_link_of_the_docs_pages_resolves():
    pages = sorted((ROOT / "docs").glob("*.md"))
    assert pages
    assert not [link for page in pages for link in broken_links(page)]


def test_the_readme_runs_what_ci_runs():
    """CI (.ci/run) runs `make test`; the README's two commands give that same command."""
    ci = (ROOT / ".ci" / "run").read_text()
    readme = (ROOT / "README.md").read_text()
    block = re.findall(r"```bash\n(.*?)```", readme.split("## Two commands", 1)[1], flags=re.S)[0]
    commands = [line.split("#")[0].strip() for line in block.splitlines()]
    assert "make test" in commands and "\nmake test\n" in ci


def test_the_checks_catch_what_they_are_for(tmp_path):
    long_row = "| " + "x" * 201 + " | `a \\| b` |\n"
    fenced_row = "```\n| " + "y" * 300 + " |\n```\n"
    text = "| a | b |\n|---|---|\n" + long_row + fenced_row
    assert [len(cell) for _, cell in table_cells(text)] == [1, 1, 3, 3, 201, 8]
    assert heading_anchors("# TD7's options (`--recipe td7-cpu`)\n## A\n## A\n") == {
        "td7s-options---recipe-td7-cpu",
        "a",
        "a-1",
    }
    page = tmp_path / "page.md"
    (tmp_path / "other.md").write_text("# Here\n")
    page.write_text(
        "[ok](other.md#here) [no](other.md#there) [gone](missing.md) [web](https://x)\n"
    )
    assert broken_links(page) == [
        "page.md: other.md#there (no such heading)",
        "page.md: missing.md (no such file)",
    ]


def test_a_30_seed_row_keeps_every_seed_in_a_short_cell():
    """RESULTS.md's rows are written by bench.results: 30 seeds' returns fit in one cell, with
    runs of equal values collapsed and every seed's value still there, in order."""

    def expanded(text: str) -> list[str]:
        values = []
        for part in text.split(" / "):
            value, _, count = part.partition(" (x")
            values += [value] * (int(count.rstrip(")")) if count else 1)
        return values

    finals = [500.0] * 8 + [499.4] + [500.0] * 21
    text = results.per_seed_text(finals)
    assert text == "500 (x8) / 499 / 500 (x21)"
    assert expanded(text) == [f"{value:,.0f}" for value in finals]
    assert results.per_seed_text([1.0, 1.0, 2.5]) == "1.0 / 1.0 / 2.5"  # short lists as they were
    # 30 different values: whole numbers, every seed in order, in the form figures read back
    spread = [40.0 + 0.3 * seed for seed in range(30)]
    compact = results.per_seed_text(spread)
    assert len(compact) <= 150 and expanded(compact) == [f"{v:,.0f}" for v in spread]
    # runs of equal values that do not fit collapsed to one decimal: whole and collapsed again
    # (recurrent PPO's CartPoleNoVel row, whose rounded list alone was 207 characters)
    novel = [500, 474, 500, 472, 500, 500, 158, 500, 279, 178, 351, 500, 500, 244, 404, 288, 372]
    novel = [float(v) + 0.2 for v in novel + [492, 500, 500, 483, 409, 500, 497, 479] + [500] * 5]
    compact = results.per_seed_text(novel)
    assert compact.startswith("500 / 474 / 500 / 472 / 500 (x2) / 158 / 500 / 279")
    assert compact.endswith(" / 500 (x5)") and len(compact) == 155
    assert expanded(compact) == [f"{v:,.0f}" for v in novel]
    summary = {
        "seeds": list(range(30)),
        "env_steps": 60_000,
        "final": finals,
        "final_mean": 499.98,
        "final_ci": (499.9, 500.0),
        "final_iqm": 500.0,
        "best_mean": 500.0,
    }
    for name, row in results.ROWS.items():
        line = results.row_cells(name, row, summary, {"wall_clock": 34.0, "load": "1.2-1.7"})
        assert max(len(cell) for _, cell in table_cells(line)) <= MAX_CELL, name
