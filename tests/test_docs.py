"""The documentation site (docs/): its link check, its generated tables, and a whole build.

`make docs` (and so CI) builds the site with warnings as errors, and after writing the HTML the
site's extension (docs/_ext/rl_jax_docs.py) warns about every local link or image that points at
nothing. The fast tests here check that checker and the env table's coverage; the slow one
builds the whole site as `make docs` does.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("sphinx", reason="the docs tools are not installed: pip install -e '.[docs]'")

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import rl_jax_docs  # noqa: E402  (needs sphinx, and the path above)


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def test_broken_references_finds_missing_files_anchors_and_images(tmp_path):
    write(tmp_path / "index.html", '<h1 id="top">x</h1><a href="guide/page.html#usage">ok</a>')
    write(
        tmp_path / "guide" / "page.html",
        '<section id="usage"></section>'
        '<a href="../index.html#top">ok</a> <a href="#usage">ok</a> <a href="..">ok</a>'
        '<a href="https://example.org/x.html">external</a> <a href="mailto:a@b.c">mail</a>'
        '<a href="missing.html">file</a> <a href="../index.html#nowhere">anchor</a>'
        '<img src="../_images/there.png"> <img src="gone.png">',
    )
    write(tmp_path / "_images" / "there.png", "")
    problems = rl_jax_docs.broken_references(tmp_path)
    assert problems == [
        "guide/page.html: link missing.html points at no file",
        "guide/page.html: link ../index.html#nowhere points at no anchor",
        "guide/page.html: image gone.png points at no file",
    ]


def test_learner_figures_match_the_name_as_a_word(tmp_path):
    names = ("halfcheetah_td3.png", "td3-hopper.gif", "td7_ant.png", "notes_td3.txt")
    names += ("curves_hopper.png", "curves_pendulum.png", "policy_ant.gif", "speed_x.png")
    for name in names:
        write(tmp_path / name, "")
    write(
        tmp_path / "manifest.toml",
        '[curves.hopper]\ntitle = "Hopper-v5"\nruns = ["runs/results/td3-hopper"]\n'
        '[curves.pendulum]\ntitle = "Pendulum-v1: SAC"\nlabels = ["SAC", "TD3"]\n'
        '[gifs.ant]\nrun = "runs/sac_ant"\n[speed.x]\ntitle = "TD3 updates/s"\n',
    )
    found = rl_jax_docs.figure_files(tmp_path, ["td3", "ddpg"])
    assert [(path.name, caption) for path, caption in found] == [
        ("curves_hopper.png", "Hopper-v5"),
        ("curves_pendulum.png", "Pendulum-v1: SAC"),
        ("halfcheetah_td3.png", "halfcheetah td3"),
        ("speed_x.png", "TD3 updates/s"),
        ("td3-hopper.gif", "td3-hopper"),
    ]
    assert [p.name for p, _ in rl_jax_docs.figure_files(tmp_path, ["sac"])] == [
        "curves_pendulum.png",
        "policy_ant.gif",
    ]
    assert rl_jax_docs.figure_files(tmp_path / "absent", ["td3"]) == []


def test_env_gifs_are_found_by_the_env_name(tmp_path):
    for name in ("policy_halfcheetah.gif", "policy_rocket_settle.gif", "curves_hopper.png"):
        write(tmp_path / name, "")
    gifs = rl_jax_docs.policy_gifs(tmp_path)
    assert gifs[rl_jax_docs.env_key("rl_jax/HalfCheetah-v5")].name == "policy_halfcheetah.gif"
    assert gifs[rl_jax_docs.env_key("rl_jax/RocketSettle-v0")].name == "policy_rocket_settle.gif"
    assert len(gifs) == 2


def test_an_env_without_its_own_gif_shows_a_learners_in_the_preferred_order(tmp_path):
    names = ("policy_ppo_hopper.gif", "policy_sac_hopper.gif", "policy_ppo_walker2d.gif")
    for name in (*names, "policy_ant.gif", "policy_sac_ant.gif"):
        write(tmp_path / name, "")
    gifs = {key: path.name for key, path in rl_jax_docs.policy_gifs(tmp_path).items()}
    assert gifs == {
        "hopper": "policy_sac_hopper.gif",  # SAC before PPO (GIF_LEARNERS)
        "walker2d": "policy_ppo_walker2d.gif",
        "ant": "policy_ant.gif",  # a GIF named by the env alone comes first
    }


def test_env_table_describes_every_registered_env():
    # The library's own registry, read in a fresh process: test modules register envs of their
    # own in this one.
    ids = subprocess.run(
        [sys.executable, "-c", "from rl_jax import envs; print('\\n'.join(envs.registered_ids()))"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    page = (DOCS / "environments.md").read_text(encoding="utf-8")
    block = re.search(r"```\{env-table\}\n(.*?)```", page, re.S)
    assert block, "docs/environments.md has no env-table block"
    described = {line.split(": ", 1)[0] for line in block.group(1).splitlines() if line.strip()}
    assert described == set(ids)


@pytest.mark.slow
def test_the_site_builds_without_warnings(tmp_path):
    out = tmp_path / "html"
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html"]
    result = subprocess.run(
        [*command, str(DOCS), str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr[-4000:]
    pages = [p for p in DOCS.rglob("*.md") if "_build" not in p.parts]
    for page in pages:
        html = out / page.relative_to(DOCS).with_suffix(".html")
        assert html.exists(), f"{page.relative_to(ROOT)} was not built"
    assert rl_jax_docs.broken_references(out) == []
