"""``make docs-check`` (scripts/docs_check.py) finds each kind of problem it is there to find, in
a small site written here, and nothing on a page without them. Needs Chromium and its driver
(scripts/docs_check.sh installs them; CI runs it before the tests): skipped without them."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(
    not (shutil.which("chromium") and shutil.which("chromedriver")),
    reason="needs chromium and chromedriver (scripts/docs_check.sh)",
)


def load_checker():
    spec = importlib.util.spec_from_file_location("docs_check", ROOT / "scripts" / "docs_check.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


PNG = bytes.fromhex(  # 1 x 1 pixel
    "89504e470d0a1a0a0000000d49484452000000010000000108060000001f15c489"
    "0000000d49444154789c6360f8cfc0f01f0005000201a6a4e7b90000000049454e44ae426082"
)


def page(body: str) -> str:
    """A page laid out as furo lays one out: a 736 px content column, an article inside it."""
    return (
        "<!doctype html><html><head><meta charset='utf-8'><style>"
        "body{margin:0;font:16px sans-serif} .content{width:736px;padding:0 48px}"
        ".table-wrapper{overflow-x:auto} pre{overflow-x:auto}</style></head>"
        f"<body><div class='content'><article id='top'>{body}</article></div></body></html>"
    )


WIDE_CELL = "<td><img src='dot.png' style='width:900px;height:4px'></td>"


def test_each_problem_is_found_and_a_clean_page_passes(tmp_path: Path) -> None:
    checker = load_checker()
    (tmp_path / "dot.png").write_bytes(PNG)
    pages = {
        "index.html": page(
            "<h1 id='a'>Fine</h1><p>Text, <a href='other.html#there'>a link</a>, "
            "<img src='dot.png'>, <code>--a-flag</code> and <code>\\(x\\)</code> in code.</p>"
            "<pre>" + "a long line of code " * 80 + "</pre>"
        ),
        "other.html": page("<h1 id='there'>Other</h1>"),
        "broken.html": page(
            "<img src='missing.png'>"
            "<p>raw \\(\\pi_\\phi\\) maths</p>"
            "<div class='table-wrapper'><table><tr>" + WIDE_CELL + "</tr></table></div>"
            "<p><a href='nowhere.html'>gone</a> <a href='other.html#nothing'>no anchor</a></p>"
            "<div style='width:300px'><code>--updates-per-iteration</code> "
            "<code>--updates-per-iteration</code> <code>--updates-per-iteration</code></div>"
        ),
        "wide.html": page("<div style='width:2000px'>wide</div>"),
    }
    for name, text in pages.items():
        (tmp_path / name).write_text(text, encoding="utf-8")

    problems = checker.check_site(tmp_path, sorted(pages))

    assert not [p for p in problems if p.startswith(("index.html", "other.html"))], problems
    broken = "\n".join(p for p in problems if p.startswith("broken.html"))
    for expected in (
        "broken image missing.png",
        'raw TeX "\\("',
        "clipped, ",
        "link to a missing file: nowhere.html",
        "link to a missing anchor: other.html#nothing",
        "flag broken over lines: --updates-per-iteration",
    ):
        assert expected in broken, (expected, problems)
    wide = [p for p in problems if p.startswith("wide.html")]
    assert any("page is" in p for p in wide) and any("past the content column" in p for p in wide)
