"""The built documentation site read in headless Chromium, as a reader's browser shows it.

    python scripts/docs_check.py [docs/_build/html]    (``make docs-check``)

Every page of the site is loaded from a local HTTP server on 127.0.0.1 in one browser, with no
network, at a 1,280 px wide window, after its maths has been typeset. A page fails when:

- an image is broken (it did not load, or has no pixels);
- a resource came from anywhere but the site itself (the site must work offline);
- maths is not typeset: a maths element without its rendered form, a MathJax error, or a raw TeX
  delimiter (``\\(``, ``\\)``, ``\\[``, ``\\]``, ``$$``) left in the text outside code;
- the page is wider than the window (``scrollWidth`` of the document past its ``clientWidth``);
- an element of the page's content is clipped (a box that scrolls or hides its overflow, with
  content wider than itself: a table in its scrolling wrapper) or runs past the right edge of the
  content column (an image, a word too long for its column). Code blocks are exempt: they scroll
  inside a box that itself fits;
- an option flag (a literal starting ``--``) is broken over two lines;
- a link or image inside the site names a file that does not exist, or an ``#anchor`` that is
  not on its page.

Chromium is driven through ``chromedriver``'s W3C WebDriver HTTP interface with the standard
library only; the checks inside a page are ``docs_check.js`` beside this file;
``scripts/docs_check.sh`` installs Debian's ``chromium``, ``chromium-driver`` and the fonts.
Prints one line per problem and exits 1 when there is any (2 when there is no built site).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import html.parser
import http.server
import json
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlsplit

WIDTH, HEIGHT = 1280, 1000  # the window; --width checks another
#: How far (px) an element may reach past the content column: furo's headings and table wrappers
#: do by 8 px (half a rem), into the column's own padding.
BLEED = 8
#: Chromium's flags: headless, no sandbox (root in a container), nothing that reaches a network.
CHROMIUM_ARGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--disable-extensions",
    "--hide-scrollbars",
]
#: Pages that are Sphinx's own machinery, not the documentation.
SKIPPED = {"search.html", "genindex.html", "py-modindex.html"}

#: The checks run in the page (WebDriver's asynchronous script), beside this file.
PAGE_SCRIPT = (Path(__file__).parent / "docs_check.js").read_text(encoding="utf-8")


class WebDriverError(RuntimeError):
    """chromedriver answered with an error."""


class Browser:
    """One Chromium session through chromedriver's W3C WebDriver HTTP interface."""

    def __init__(self, chromium: str, chromedriver: str, profile: str, width: int = WIDTH) -> None:
        self.width = width
        port = free_port()
        self.base = f"http://127.0.0.1:{port}"
        self.driver = subprocess.Popen(
            [chromedriver, f"--port={port}"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            self._wait_ready()
            args = [*CHROMIUM_ARGS, f"--window-size={width},{HEIGHT}", f"--user-data-dir={profile}"]
            options = {"binary": chromium, "args": args}
            capabilities = {"browserName": "chrome", "goog:chromeOptions": options}
            value = self._call("POST", "/session", {"capabilities": {"alwaysMatch": capabilities}})
            self.session = f"/session/{value['sessionId']}"
            self._call("POST", f"{self.session}/timeouts", {"script": 60_000, "pageLoad": 60_000})
        except BaseException:
            self.driver.kill()
            self.driver.wait()
            raise

    def _call(self, method: str, path: str, body: dict[str, Any] | None = None) -> Any:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.base + path, data=data, method=method)
        request.add_header("Content-Type", "application/json")
        try:
            with urllib.request.urlopen(request, timeout=120) as response:
                return json.load(response)["value"]
        except urllib.error.HTTPError as error:
            value = json.load(error).get("value", {})
            raise WebDriverError(f"{value.get('error')}: {value.get('message')}") from None

    def _wait_ready(self) -> None:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if self.driver.poll() is not None:
                raise WebDriverError(f"chromedriver exited with status {self.driver.returncode}")
            with contextlib.suppress(OSError):
                if self._call("GET", "/status").get("ready"):
                    return
            time.sleep(0.05)
        raise WebDriverError("chromedriver did not start in 30 s")

    def problems(self, url: str) -> list[str]:
        """Load ``url`` and run the page's checks on it."""
        self._call("POST", f"{self.session}/url", {"url": url})
        body = {"script": PAGE_SCRIPT, "args": [self.width, BLEED]}
        return self._call("POST", f"{self.session}/execute/async", body)

    def links(self) -> list[dict[str, str]]:
        """The current page's ids, and the targets of its links and images, resolved."""
        script = (
            "return {ids: [...document.querySelectorAll('[id], a[name]')]"
            ".map((e) => e.id || e.getAttribute('name')),"
            " urls: [...document.querySelectorAll('a[href], img[src]')]"
            ".map((e) => e.href || e.src)};"
        )
        return self._call("POST", f"{self.session}/execute/sync", {"script": script, "args": []})

    def close(self) -> None:
        with contextlib.suppress(OSError, WebDriverError):
            self._call("DELETE", self.session)
        self.driver.terminate()
        try:
            self.driver.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.driver.kill()
            self.driver.wait()


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (for chromedriver)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@contextlib.contextmanager
def serve(folder: Path) -> Iterator[str]:
    """``folder`` served on 127.0.0.1 for the length of the block: its base URL."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, format: str, *args: Any) -> None:
            pass

    handler = functools.partial(Quiet, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()


def pages_of(site: Path) -> list[str]:
    """The site's HTML pages, relative to it, but Sphinx's search and index pages."""
    pages = []
    for path in sorted(site.rglob("*.html")):
        name = path.relative_to(site).as_posix()
        if name.startswith("_") or name in SKIPPED:
            continue
        pages.append(name)
    return pages


def broken_links(site: Path, base: str, urls: list[str], ids: dict[str, set[str]]) -> list[str]:
    """Each of a page's links and image sources into the site (``urls``, resolved by the browser
    against ``base``) whose file or ``#anchor`` does not exist. ``ids``: each loaded page's ids;
    those of other pages are read from their HTML when asked for."""
    problems = []
    for url in urls:
        if not url.startswith(base):
            continue  # another site, or mailto: (the page check sees what is loaded from where)
        shown = url[len(base) :]
        parts = urlsplit(shown)
        target = site / unquote(parts.path)
        if not parts.path or target.is_dir():
            target = target / "index.html"
        if not target.is_file():
            problems.append(f"link to a missing file: {shown}")
        elif parts.fragment and target.suffix == ".html":
            name = target.relative_to(site).as_posix()
            if name not in ids:
                ids[name] = anchors_of(target)
            if unquote(parts.fragment) not in ids[name]:
                problems.append(f"link to a missing anchor: {shown}")
    return problems


class _Ids(html.parser.HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.found: set[str] = set()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if value and (name == "id" or (tag == "a" and name == "name")):
                self.found.add(value)


def anchors_of(page: Path) -> set[str]:
    """The ids of a page not loaded in the browser (Sphinx's own pages), read from its HTML."""
    parser = _Ids()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser.found


def find(program: str, *others: str) -> str:
    """The path of ``program`` (or of the first of ``others`` found), else exit with one line."""
    for name in (program, *others):
        path = shutil.which(name)
        if path:
            return path
    raise SystemExit(
        f"error: {program} not found; scripts/docs_check.sh installs Debian's chromium and "
        "chromium-driver"
    )


def check_site(site: Path, pages: list[str] | None = None, width: int = WIDTH) -> list[str]:
    """``page: problem`` for every problem of the built site in ``site``."""
    chromium = find("chromium", "chromium-browser", "google-chrome")
    chromedriver = find("chromedriver")
    pages = pages_of(site) if pages is None else pages
    problems: list[str] = []
    ids: dict[str, set[str]] = {}
    targets: dict[str, list[str]] = {}
    with tempfile.TemporaryDirectory(prefix="docs-check-") as profile, serve(site) as base:
        browser = Browser(chromium, chromedriver, profile, width)
        try:
            for page in pages:
                problems += [f"{page}: {p}" for p in browser.problems(base + page)]
                found = browser.links()
                ids[page] = set(found["ids"])
                targets[page] = found["urls"]
        finally:
            browser.close()
    for page in pages:
        problems += [f"{page}: {p}" for p in broken_links(site, base, targets[page], ids)]
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("site", nargs="?", default="docs/_build/html", type=Path)
    parser.add_argument("--width", type=int, default=WIDTH, help="the window's width in px")
    args = parser.parse_args(argv)
    site: Path = args.site.resolve()
    if not (site / "index.html").is_file():
        print(f"error: no built site in {args.site}; run `make docs` first", file=sys.stderr)
        return 2
    start = time.monotonic()
    pages = pages_of(site)
    problems = check_site(site, pages, args.width)
    for problem in problems:
        print(problem)
    seconds = time.monotonic() - start
    count = len(problems)
    verdict = f"{count} problem{'' if count == 1 else 's'}" if count else "no problems"
    where = f"{len(pages)} pages in Chromium at {args.width} px"
    print(f"docs-check: {where}, {verdict} ({seconds:.1f} s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
