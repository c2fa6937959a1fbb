"""Sphinx configuration of the rl_jax documentation site (``make docs``).

Pages are Markdown (MyST). Every ``docs/*.md`` page joins the site through the glob toctree of
``index.md``; the tables of learner options, recipes and environments are generated from the code
at build time by ``_ext/rl_jax_docs.py``, so they cannot go stale.
"""

import os
import sys
from pathlib import Path

# The generated tables build envs and learners: JAX's CPU backend is all they need.
os.environ.setdefault("JAX_PLATFORMS", "cpu")

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path[:0] = [str(DOCS / "_ext"), str(ROOT)]

project = "rl_jax"
author = "the rl_jax authors"
copyright = "the rl_jax authors, Apache-2.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "rl_jax_docs",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# MyST: $...$ and $$...$$ maths, ::: fences, and an anchor for every heading level as GitHub
# makes them, so links like page.md#a-heading (and RESULTS.md's own #a-heading) resolve.
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 6

# MathJax from the site itself, not from a CDN, so that maths renders offline: rl_jax_docs copies
# MathJax 3 from the sphinx-mathjax-offline package (the docs extra) into _static/mathjax.
mathjax_path = "mathjax/tex-chtml.js"

# The API reference: signatures with their type hints and defaults as written, members in source
# order. Docstrings are reST prose with ``literals``, not Google or NumPy sections, so napoleon is
# left out: it would read a property's first line "The results: a ..." as a type.
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_typehints_format = "short"

# Warnings are errors (``make docs`` passes -W); nitpicky checks every cross-reference, except
# those to other projects' types (the site has no network for intersphinx) and type aliases that
# autodoc cannot link.
nitpicky = True
nitpick_ignore_regex = [
    (
        r"py:.*",
        r"(jax|jaxlib|flax|optax|orbax|numpy|np|matplotlib|gymnasium|mujoco|pgx|mctx)(\..*)?",
    ),
    (r"py:.*", r"(pathlib|collections|typing|typing_extensions|argparse|types)\..*"),
    (r"py:.*", r"(Path|Any|Callable|Array|PRNGKey|Self|TypeAlias|NamedTuple|Protocol)"),
    # pieces of a dataclass signature that Sphinx splits at its commas (``tuple[int, ...]``)
    (r"py:class", r"(tuple|list|dict)\[.*"),
    # type variables, and the internal classes behind a public function's return value
    (r"py:class", r"(rl_jax\.)?envs\.core\.core\.(StateT|ParamsT)"),
    (r"py:class", r"(rl_jax\.run\.policy\.)?LoadedPolicy"),
    (r"py:class", r"(rl_jax\.)?envs\.adapters\.gymnasium_host\.HostGymnasiumEnv"),
    (r"py:class", r"rl_jax\.training\.algorithm\.(DataclassState|ConfigT)"),
    (r"py:class", r"rl_jax\.run\.plots\.FinalResult"),
    # a match's player (a Callable alias) and self-play's stored positions, in AlphaZero's API
    (r"py:class", r"(Player|Positions)"),
    # a learner's Config, which its page documents as a table of options rather than a class
    (r"py:class", r"rl_jax\.agents\.\w+\.Config"),
]
# RESULTS.md and BENCHMARKS.md, included as they are, skip heading levels here and there.
suppress_warnings = ["myst.header"]

html_theme = "furo"
html_title = "rl_jax"
html_static_path = ["_static"]
html_css_files = ["rl_jax.css"]  # tables that fit the column, flags that never break
html_show_sourcelink = False
