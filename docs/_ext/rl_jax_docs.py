"""Sphinx directives that write the site's tables from the code, so that they never go stale.

``learner-options NAME``
    the learner's ``Config`` and ``Hyperparams`` fields: flag, default, meaning (the same
    comments ``--help`` reads). ``:compare: OTHER`` adds the fields whose defaults differ in the
    learner ``OTHER`` (DDPG against TD3); ``:variant: module:Class`` adds the fields a config
    variant adds or changes (DQN's ``PixelConfig``).
``learner-recipes NAME``
    the learner's recipes (``rl_jax.training.recipes``): name, envs, summary, and env steps per
    seed: the recipe's own budget, else the default budgets of the scripts that would run it,
    read from ``experiments/*.py`` (``Script(...)``, ``cli.main(...)``).
``learner-figures NAME [NAME ...]``
    every image under ``docs/figures/`` that shows one of the learners: the name is a word of
    the file name (``halfcheetah_td3.png``) or of what ``docs/figures/manifest.toml`` says the
    image is drawn from (its title, labels, run directories); or one line saying there is none.
    Each image's caption is its manifest entry's ``caption``, else its ``title``.
``manifest-figure FILE``
    one image of ``docs/figures/`` (``aggregate_suite.png``) with its manifest caption.
``env-table``
    every registered env id with its observation and action spaces and episode limit (built
    from ``envs.make``), and its policy GIF where ``docs/figures/policy_NAME.gif`` exists; the
    directive's content gives each id's parity line as ``ID: text``.
    An id registered but not described, or described but not registered, fails the build.

Every inline literal that is an option flag (``--updates-per-iteration``) gets the class
``rl-jax-flag`` (``MarkFlags``), which ``_static/rl_jax.css`` keeps on one line.

After the HTML is written, ``copy_mathjax`` puts MathJax (from the ``sphinx-mathjax-offline``
package) into ``_static/mathjax``, where ``conf.py``'s ``mathjax_path`` points, so that maths
renders without a network; and ``check_output`` reads every page: a local link (``href``) or image
(``src``) whose file or ``#anchor`` does not exist is a warning, so ``-W`` fails the build, and so
is an image of ``docs/figures/`` that no page shows.
"""

from __future__ import annotations

import ast
import dataclasses
import html.parser
import importlib
import importlib.util
import inspect
import re
import shutil
import tomllib
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlsplit

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.application import Sphinx
from sphinx.transforms import SphinxTransform
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".gif", ".svg", ".jpg", ".jpeg", ".webp")
FIGURES = "figures"


# ---- building blocks --------------------------------------------------------------------------

_CODE = re.compile(r"``(.+?)``|`(.+?)`")


def inline(text: str) -> list[nodes.Node]:
    """``text`` as docutils nodes, its ``code`` and ```code``` spans as literals."""
    parts: list[nodes.Node] = []
    position = 0
    for match in _CODE.finditer(text):
        if match.start() > position:
            parts.append(nodes.Text(text[position : match.start()]))
        code = match.group(1) or match.group(2)
        parts.append(nodes.literal(code, code))
        position = match.end()
    if position < len(text):
        parts.append(nodes.Text(text[position:]))
    return parts


Cell = str | nodes.Node


def table(headers: list[str], rows: list[list[Cell]], widths: list[int]) -> nodes.table:
    """A docutils table; a ``str`` cell is text with its code spans as literals."""
    group = nodes.tgroup(cols=len(headers))
    for width in widths:
        group += nodes.colspec(colwidth=width)

    def row_of(cells: list[Cell]) -> nodes.row:
        row = nodes.row()
        for cell in cells:
            entry = nodes.entry()
            entry += nodes.paragraph("", "", *inline(cell)) if isinstance(cell, str) else cell
            row += entry
        return row

    head = nodes.thead()
    head += row_of(list(headers))
    body = nodes.tbody()
    for cells in rows:
        body += row_of(cells)
    group += head
    group += body
    result = nodes.table(classes=["rl-jax-generated"])
    result += group
    return result


def literal(text: str, *classes: str) -> nodes.paragraph:
    """A table cell of one code span (with ``classes``)."""
    return nodes.paragraph("", "", nodes.literal(text, text, classes=list(classes)))


def describe(value: Any) -> str:
    """A default as a flag would take it (``rl_jax.run.flags``), ``(empty)`` for an empty tuple."""
    from rl_jax.run.flags import describe_default

    return describe_default(value) or "(empty)"


def learner(name: str) -> Any:
    """A learner object by its ``--algo`` name."""
    from rl_jax.run.learners import resolve

    return resolve(name)


def imported(reference: str) -> Any:
    """``module:attribute`` imported."""
    module, _, attribute = reference.partition(":")
    return getattr(importlib.import_module(module), attribute)


# ---- learner options ----------------------------------------------------------------------------


def field_defaults(cls: type) -> dict[str, Any]:
    """Each field's default in the class itself, before any recipe (flags only)."""
    from rl_jax.run.flags import NOT_FLAGS

    defaults = {}
    for field in dataclasses.fields(cls):
        if field.name in NOT_FLAGS:
            continue
        if field.default is not dataclasses.MISSING:
            defaults[field.name] = field.default
        elif field.default_factory is not dataclasses.MISSING:
            defaults[field.name] = field.default_factory()
    return defaults


def options_rows(cls: type, only: set[str] | None = None) -> list[list[Cell]]:
    """One row per field of ``cls`` (or of ``only``): flag, default, meaning."""
    from rl_jax.run.field_docs import field_docs
    from rl_jax.run.flags import flag_name

    docs = field_docs(cls)
    rows: list[list[Cell]] = []
    for name, default in field_defaults(cls).items():
        if only is not None and name not in only:
            continue
        rows.append([literal(flag_name(name)), literal(describe(default)), docs.get(name, "")])
    return rows


def changed_fields(base: type, other: type) -> set[str]:
    """Fields of ``other`` that ``base`` lacks or whose defaults differ."""
    mine, theirs = field_defaults(base), field_defaults(other)
    return {n for n, v in theirs.items() if n not in mine or describe(mine[n]) != describe(v)}


def section(title: str, intro: str, body: nodes.Node) -> list[nodes.Node]:
    """A titled table with a line of introduction."""
    return [nodes.rubric(title, title), nodes.paragraph("", "", *inline(intro)), body]


OPTION_HEADERS = ["flag", "default", "meaning"]
OPTION_WIDTHS = [26, 14, 60]


class LearnerOptions(SphinxDirective):
    """The option tables of one learner (see the module docstring)."""

    required_arguments = 1
    option_spec = {"compare": directives.unchanged, "variant": directives.unchanged}

    def run(self) -> list[nodes.Node]:
        self.env.note_reread()  # generated from the code: re-read on every build
        algorithm = learner(self.arguments[0])
        config, hparams = algorithm.config_type, algorithm.hparams_type
        out = section(
            f"Config: static settings of {algorithm.name}",
            "Shapes, loop counts and sizes: a change compiles another program. Each is a "
            "flag of the scripts and a keyword of ``rl_jax.train``. The defaults are the "
            "learner's own: a recipe (below) may set others for its envs, and a script's "
            "``--help`` shows the values it would run with.",
            table(OPTION_HEADERS, options_rows(config), OPTION_WIDTHS),
        )
        out += section(
            f"Hyperparams: what a sweep of {algorithm.name} may vary",
            "Array leaves of the train state: ``--grid NAME=a,b`` trains every value in one "
            "compiled program.",
            table(OPTION_HEADERS, options_rows(hparams), OPTION_WIDTHS),
        )
        if "compare" in self.options:
            other = learner(self.options["compare"])
            for mine, theirs, kind in (
                (config, other.config_type, "Config"),
                (hparams, other.hparams_type, "Hyperparams"),
            ):
                changed = changed_fields(mine, theirs)
                if changed:
                    out += section(
                        f"{other.name}: its {kind} defaults where they differ",
                        f"``{other.name}`` is the same learner with these defaults.",
                        table(OPTION_HEADERS, options_rows(theirs, changed), OPTION_WIDTHS),
                    )
        if "variant" in self.options:
            variant = imported(self.options["variant"])
            changed = changed_fields(config, variant)
            out += section(
                f"{variant.__name__}: what it adds or changes",
                inspect.cleandoc(variant.__doc__ or "").split("\n\n")[0].replace("\n", " "),
                table(OPTION_HEADERS, options_rows(variant, changed), OPTION_WIDTHS),
            )
        return out


# ---- recipes ----------------------------------------------------------------------------------

#: The runnable scripts, whose defaults (learner, env, budget) the recipe tables name.
EXPERIMENTS = "experiments"


@dataclasses.dataclass(frozen=True)
class ScriptBudget:
    """What one script of ``experiments/`` runs when given no flags: its learner (the name it is
    imported as, ``td3``; None: any learner, ``--algo``), env (None: any, ``--env``) and budget."""

    script: str
    learner: str | None
    env_id: str | None
    total_steps: int


def _value(node: ast.expr | None, names: dict[str, Any]) -> Any:
    """A literal, or a name bound to one in the script, as the script would see it."""
    if node is None:
        return None
    if isinstance(node, ast.Name) and node.id in names:
        return names[node.id]
    try:
        return ast.literal_eval(node)
    except (ValueError, TypeError, SyntaxError):  # a name: the learner it was imported as
        return node.id if isinstance(node, ast.Name) else None


def _call_name(call: ast.Call) -> str:
    func = call.func
    return func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")


def _script_budget(path: Path, found: dict[str, ScriptBudget]) -> ScriptBudget | None:
    """A script's defaults, read from its source without running it: ``Script(learner, env,
    total_steps=...)``, ``cli.main(learner, env, __doc__, total_steps=...)``, or
    ``dataclasses.replace(other.SCRIPT, ...)`` of another script's."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: dict[str, Any] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
            for target in node.targets:
                if isinstance(target, ast.Name):
                    names[target.id] = node.value.value
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        keywords = {k.arg: k.value for k in node.keywords if k.arg}
        steps = _value(keywords.get("total_steps"), names)
        name = _call_name(node)
        if name in ("Script", "main") and len(node.args) >= 2:
            learner, env_id = (_value(a, names) for a in node.args[:2])
            default = ScriptBudget.__dataclass_fields__["total_steps"].default
            return ScriptBudget(path.name, learner, env_id, steps or default)
        if name == "replace" and node.args and isinstance(node.args[0], ast.Attribute):
            base = found.get(f"{getattr(node.args[0].value, 'id', '')}.py")
            if base is not None:
                algorithm = keywords.get("algorithm")
                return ScriptBudget(
                    path.name,
                    _value(algorithm, names) if algorithm else base.learner,
                    _value(keywords.get("env_id"), names) or base.env_id,
                    steps or base.total_steps,
                )
    return None


def script_budgets(root: Path) -> list[ScriptBudget]:
    """The defaults of every script in ``experiments/`` that trains one learner on one env, or
    any learner on any env (``train.py``); the others (``sweep.py``, reports) are left out."""
    found: dict[str, ScriptBudget] = {}
    pending = sorted((root / EXPERIMENTS).glob("*.py"))
    for _ in range(len(pending)):  # rounds: a script built on another's SCRIPT after that one
        for path in list(pending):
            budget = _script_budget(path, found)
            if budget is not None:
                found[path.name] = budget
                pending.remove(path)
    return sorted(found.values(), key=lambda b: b.script)


def budget_cell(recipe: Any, algorithm: Any, scripts: list[ScriptBudget]) -> str:
    """A recipe's env steps per seed: its own budget, else the default budgets of ``train.py``
    (any learner on any env) and of the scripts that run its learner on one of its envs."""
    if recipe.total_steps:
        return f"{recipe.total_steps:,}"
    by_budget: dict[int, list[str]] = {}
    for budget in scripts:
        if budget.learner is not None:
            if budget.env_id not in recipe.envs:
                continue
            try:
                if learner(budget.learner).recipes is not algorithm.recipes:
                    continue
            except Exception:  # a script's first argument that is not a learner's name
                continue
        by_budget.setdefault(budget.total_steps, []).append(f"``{budget.script}``")
    parts = [f"{steps:,} ({', '.join(names)})" for steps, names in by_budget.items()]
    return "; ".join(parts) + ("" if recipe.envs else "; a script's own on its env")


RECIPES_NOTE = (
    "Steps per seed: a recipe's own budget where it sets one; otherwise the budget of the run, "
    "``--total-steps`` or ``total_steps=``, else the default of the script that runs it (named "
    "beside its number; ``train.py``'s for any learner, ``rl_jax.train``'s is the same)."
)


class LearnerRecipes(SphinxDirective):
    """The recipes of one learner (see the module docstring)."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        self.env.note_reread()
        algorithm = learner(self.arguments[0])
        scripts = script_budgets(Path(self.env.srcdir).parent)
        rows: list[list[Cell]] = []
        for recipe in algorithm.recipes:
            envs_cell = ", ".join(f"``{e}``" for e in recipe.envs) if recipe.envs else "any env"
            budget = budget_cell(recipe, algorithm, scripts)
            name = literal(recipe.name, "rl-jax-name")  # kept on one line, as flags are
            rows.append([name, envs_cell, recipe.about, budget])
        if not rows:
            return [nodes.paragraph("", "", *inline("No recipes: the defaults above."))]
        headers = ["recipe", "for", "what it is", "steps per seed"]
        return [
            table(headers, rows, [14, 30, 40, 16]),
            nodes.paragraph("", "", *inline(RECIPES_NOTE)),
        ]


# ---- figures ----------------------------------------------------------------------------------


#: Image name prefix -> the table of docs/figures/manifest.toml (``make figures``) that says what
#: the image ``PREFIX_KEY.png`` is drawn from: ``[curves.KEY]``, ``[gifs.KEY]``, ``[speed.KEY]``.
#: (An aggregate over the suite compares learners: it is on no one learner's page, and
#: ``manifest-figure`` shows it where a page asks.)
MANIFEST_TABLES = {"curves": "curves", "policy": "gifs", "speed": "speed", "aggregate": "aggregate"}


def manifest_entry(manifest: dict[str, Any], path: Path) -> dict[str, Any]:
    """The manifest's entry of the image ``path`` (``{}`` when it has none)."""
    prefix, _, key = path.stem.partition("_")
    entry = manifest.get(MANIFEST_TABLES.get(prefix, ""), {}).get(key, {})
    return entry if isinstance(entry, dict) else {}


def _words(*texts: Any) -> set[str]:
    words: set[str] = set()
    for text in texts:
        if isinstance(text, list | tuple):
            words |= _words(*text)
        elif isinstance(text, str):
            words |= set(re.split(r"[^a-z0-9]+", text.lower()))
    return words


def figure_files(figures_dir: Path, names: list[str]) -> list[tuple[Path, str]]:
    """``(image, caption)`` of the images that show one of the learners ``names``: the name is a
    word of the file name, or of its manifest entry's title, labels or run directories."""
    if not figures_dir.is_dir():
        return []
    manifest = read_manifest(figures_dir)
    wanted = {n.lower() for n in names}
    found = []
    for path in sorted(figures_dir.rglob("*")):
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        if path.stem.startswith("aggregate_"):  # over learners; shown by manifest-figure
            continue
        entry = manifest_entry(manifest, path)
        words = _words(path.stem, *(entry.get(k) for k in ("title", "labels", "runs", "run")))
        if words & wanted:
            found.append((path, caption_of(entry, path)))
    return found


def caption_of(entry: dict[str, Any], path: Path) -> str:
    """What the site writes under an image: its manifest entry's ``caption``, else its title."""
    return str(entry.get("caption") or entry.get("title") or path.stem.replace("_", " "))


def read_manifest(figures_dir: Path) -> dict[str, Any]:
    """``docs/figures/manifest.toml`` (``{}`` when there is none)."""
    path = figures_dir / "manifest.toml"
    return tomllib.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}


def figure_node(directive: SphinxDirective, path: Path, caption: str) -> nodes.figure:
    """An image of ``docs/figures/`` with its caption (code spans as literals)."""
    srcdir = Path(directive.env.srcdir)
    directive.env.note_dependency(str(path))
    uri = "/" + path.relative_to(srcdir).as_posix()  # to Sphinx: from the source folder
    figure = nodes.figure()
    figure += nodes.image(uri=uri, alt=caption.split(". ")[0])
    figure += nodes.caption(caption, "", *inline(caption))
    return figure


class LearnerFigures(SphinxDirective):
    """The learner's figures from ``docs/figures/`` (see the module docstring)."""

    required_arguments = 1
    optional_arguments = 8

    def run(self) -> list[nodes.Node]:
        self.env.note_reread()
        srcdir = Path(self.env.srcdir)
        files = figure_files(srcdir / FIGURES, self.arguments)
        if not files:
            text = "No figure of this learner yet: the results page has its numbers."
            return [nodes.paragraph("", "", nodes.emphasis(text, text))]
        return [figure_node(self, path, caption) for path, caption in files]


class ManifestFigure(SphinxDirective):
    """One image of ``docs/figures/`` by file name, with its manifest caption (see the module
    docstring); a name that is not there fails the build."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        self.env.note_reread()
        figures_dir = Path(self.env.srcdir) / FIGURES
        path = figures_dir / self.arguments[0]
        if not path.is_file():
            logger.warning(f"manifest-figure: no {FIGURES}/{path.name}", location=self)
            return []
        entry = manifest_entry(read_manifest(figures_dir), path)
        return [figure_node(self, path, caption_of(entry, path))]


# ---- environments -----------------------------------------------------------------------------


def space_text(space: Any) -> str:
    """``Box (17,)``, ``Box (84, 84, 4) uint8`` or ``Discrete 2``."""
    kind = type(space).__name__
    if hasattr(space, "n"):
        return f"{kind} {int(space.n)}"
    shape = tuple(int(d) for d in space.shape)
    dtype = str(getattr(space, "dtype", "float32"))
    return f"{kind} {shape}" + ("" if dtype == "float32" else f" {dtype}")


def env_rows() -> dict[str, tuple[str, str, int]]:
    """Every registered id: observation space, action space, episode limit. MuJoCo envs are
    built on the host-callback backend, which needs no compiled op (the spaces are the same)."""
    from rl_jax import envs
    from rl_jax.envs.core import registry

    rows = {}
    for env_id in envs.registered_ids():
        factory = registry.factory(env_id)
        kwargs = {}
        if "backend" in inspect.signature(factory).parameters:
            kwargs["backend"] = "mujoco_callback"
        env = factory(**kwargs)
        params = env.default_params
        rows[env_id] = (
            space_text(env.observation_space(params)),
            space_text(env.action_space(params)),
            int(env.max_episode_steps),
        )
    return rows


class EnvTable(SphinxDirective):
    """The table of registered envs (see the module docstring)."""

    has_content = True

    def run(self) -> list[nodes.Node]:
        self.env.note_reread()
        parity: dict[str, str] = {}
        for line in self.content:
            if line.strip():
                env_id, _, text = line.partition(": ")
                parity[env_id.strip()] = text.strip()
        rows = env_rows()
        where = self.get_location()
        for env_id in sorted(set(rows) - set(parity)):
            logger.warning(f"env-table: {env_id} is registered but has no line", location=where)
        for env_id in sorted(set(parity) - set(rows)):
            logger.warning(f"env-table: {env_id} is not a registered env", location=where)
        cells: list[list[Cell]] = [
            [literal(env_id), literal(obs), literal(act), f"{steps:,}", parity.get(env_id, "")]
            for env_id, (obs, act, steps) in rows.items()
        ]
        headers = ["id", "observation", "action", "episode steps", "matches"]
        widths = [24, 16, 12, 8, 40]
        srcdir = Path(self.env.srcdir)
        gifs = policy_gifs(srcdir / FIGURES)
        if gifs:  # a column of trained policies, once make figures has drawn some
            headers, widths = [*headers, "a trained policy"], [*widths, 20]
            for row, env_id in zip(cells, rows, strict=True):
                gif = gifs.get(env_key(env_id))
                if gif is None:
                    row.append("")
                    continue
                self.env.note_dependency(str(gif))
                uri = "/" + gif.relative_to(srcdir).as_posix()
                row.append(nodes.image(uri=uri, alt=f"{env_id}, a trained policy", width="160px"))
        return [table(headers, cells, widths)]


def env_key(env_id: str) -> str:
    """``rl_jax/HalfCheetah-v5`` -> ``halfcheetah``: the name without namespace, version or
    punctuation, as the GIFs of ``make figures`` are named (``policy_half_cheetah.gif`` too)."""
    name = re.sub(r"-v\d+$", "", env_id.rsplit("/", 1)[-1])
    return re.sub(r"[^a-z0-9]", "", name.lower())


#: Learners whose name may lead a GIF's (``policy_sac_hopper.gif``), in the order the env table
#: prefers them when an env has no GIF without one.
GIF_LEARNERS = ("td3", "sac", "td7", "crossq", "ppo", "ddpg", "dqn", "reinforce")


def policy_gifs(figures_dir: Path) -> dict[str, Path]:
    """``env_key`` -> ``figures/policy_KEY.gif`` or, where that is missing,
    ``figures/policy_LEARNER_KEY.gif`` of the first learner of ``GIF_LEARNERS`` that has one."""
    if not figures_dir.is_dir():
        return {}
    ranked: dict[str, tuple[int, Path]] = {}
    for path in sorted(figures_dir.glob("policy_*.gif")):
        name, rank = path.stem.removeprefix("policy_"), 0
        for index, learner in enumerate(GIF_LEARNERS, start=1):
            if name.startswith(f"{learner}_"):
                name, rank = name.removeprefix(f"{learner}_"), index
                break
        key = env_key(name)
        if key not in ranked or rank < ranked[key][0]:
            ranked[key] = (rank, path)
    return {key: path for key, (_, path) in ranked.items()}


# ---- the written site: every local link and image resolves --------------------------------------


class _Collector(html.parser.HTMLParser):
    """The ids, local links and image sources of one HTML page."""

    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.links: list[str] = []
        self.images: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if values.get("id"):
            self.ids.add(values["id"] or "")
        if tag == "a" and values.get("name"):
            self.ids.add(values["name"] or "")
        if tag == "a" and values.get("href"):
            self.links.append(values["href"] or "")
        if tag == "img" and values.get("src"):
            self.images.append(values["src"] or "")


def _is_local(url: str) -> bool:
    parts = urlsplit(url)
    return not parts.scheme and not parts.netloc and not url.startswith("mailto:")


def broken_references(outdir: Path) -> list[str]:
    """``page: what`` for each local link or image of the HTML under ``outdir`` that points at a
    missing file or a missing ``#anchor``."""
    pages: dict[Path, _Collector] = {}
    for page in sorted(outdir.rglob("*.html")):
        collector = _Collector()
        collector.feed(page.read_text(encoding="utf-8"))
        pages[page] = collector
    problems = []
    for page, collector in pages.items():
        name = page.relative_to(outdir).as_posix()
        for kind, urls in (("link", collector.links), ("image", collector.images)):
            for url in urls:
                if not _is_local(url) or url.startswith("data:"):
                    continue
                parts = urlsplit(url)
                target = (page.parent / unquote(parts.path)).resolve() if parts.path else page
                if target.is_dir():
                    target = target / "index.html"
                if not target.exists():
                    problems.append(f"{name}: {kind} {url} points at no file")
                    continue
                if parts.fragment and target.suffix == ".html":
                    ids = pages[target].ids if target in pages else set()
                    if unquote(parts.fragment) not in ids:
                        problems.append(f"{name}: {kind} {url} points at no anchor")
    return problems


# ---- option flags ------------------------------------------------------------------------------

#: A literal that is an option flag, alone or with a short value: ``--updates-per-iteration``,
#: ``--seeds 5``. The site's CSS keeps it on one line (``docs/_static/rl_jax.css``).
FLAG = re.compile(r"--[A-Za-z][\w-]*(?:[ =][^ ]{1,40})?")


class MarkFlags(SphinxTransform):
    """Adds the class ``rl-jax-flag`` to every inline literal that is an option flag."""

    default_priority = 800

    def apply(self, **kwargs: Any) -> None:
        for node in self.document.findall(nodes.literal):
            if FLAG.fullmatch(node.astext()):
                node["classes"].append("rl-jax-flag")


# ---- MathJax in the site ------------------------------------------------------------------------

#: The package that ships MathJax 3 (its ``static/mathjax``); it is imported by this name.
MATHJAX_PACKAGE = "sphinx-mathjax-offline"


def mathjax_source() -> Path:
    """The MathJax folder of the installed ``sphinx-mathjax-offline`` package."""
    spec = importlib.util.find_spec(MATHJAX_PACKAGE)
    if spec is None or spec.origin is None:
        raise RuntimeError(f"{MATHJAX_PACKAGE} is not installed: pip install -e '.[docs]'")
    return Path(spec.origin).parent / "static" / "mathjax"


def copy_mathjax(app: Sphinx, exception: Exception | None) -> None:
    """After a successful HTML build: MathJax into ``_static/mathjax``, every component and
    font, since MathJax loads the extensions a page's TeX asks for when it asks. A file already
    there with the same size is kept, so a rebuild copies nothing."""
    if exception is not None or app.builder.format != "html":
        return
    source = mathjax_source()
    target = Path(app.outdir) / "_static" / "mathjax"
    for path in source.rglob("*"):
        if not path.is_file():
            continue
        copy = target / path.relative_to(source)
        if not copy.is_file() or copy.stat().st_size != path.stat().st_size:
            copy.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, copy)


def unshown_figures(outdir: Path, figures_dir: Path) -> list[str]:
    """Each image of ``docs/figures/`` that no page of the site under ``outdir`` shows (Sphinx
    copies a page's images into ``_images/`` under their own names)."""
    shown = set()
    for page in outdir.rglob("*.html"):
        collector = _Collector()
        collector.feed(page.read_text(encoding="utf-8"))
        shown |= {unquote(urlsplit(src).path).rsplit("/", 1)[-1] for src in collector.images}
    return [
        f"{FIGURES}/{path.name} is shown on no page of the site"
        for path in sorted(figures_dir.glob("*"))
        if path.suffix.lower() in IMAGE_SUFFIXES and path.name not in shown
    ]


def check_output(app: Sphinx, exception: Exception | None) -> None:
    """After a successful HTML build: a warning for each broken local link or image, and for
    each image of ``docs/figures/`` shown on no page."""
    if exception is None and app.builder.format == "html":
        for problem in broken_references(Path(app.outdir)):
            logger.warning(problem)
        for problem in unshown_figures(Path(app.outdir), Path(app.srcdir) / FIGURES):
            logger.warning(problem)


def setup(app: Sphinx) -> dict[str, Any]:
    """Sphinx's entry point: the directives and the output check."""
    app.add_directive("learner-options", LearnerOptions)
    app.add_directive("learner-recipes", LearnerRecipes)
    app.add_directive("learner-figures", LearnerFigures)
    app.add_directive("manifest-figure", ManifestFigure)
    app.add_directive("env-table", EnvTable)
    app.add_transform(MarkFlags)
    app.connect("build-finished", copy_mathjax)
    app.connect("build-finished", check_output)
    # env_version: a change to what the transforms write re-reads every page, not only new ones
    return {
        "version": "2",
        "env_version": 2,
        "parallel_read_safe": True,
        "parallel_write_safe": True,
    }
