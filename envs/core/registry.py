"""Name -> environment registry. Entry points are imported lazily so that the pure-JAX envs do
not pay for importing MuJoCo."""

from __future__ import annotations

import ast
import importlib
from collections.abc import Callable
from typing import Any

from rl_jax.envs.core.core import Environment

# id -> "module:factory". Factories take keyword arguments (e.g. ``backend=`` for MuJoCo envs).
_ENTRY_POINTS: dict[str, str | Callable[..., Environment]] = {
    "rl_jax/Rocket-v0": "rl_jax.envs.classic.rocket:Rocket",
    "rl_jax/RocketSettle-v0": "rl_jax.envs.classic.rocket:RocketSettle",
    "rl_jax/CartPole-v1": "rl_jax.envs.classic.cartpole:CartPole",
    "rl_jax/CartPolePixels-v1": "rl_jax.envs.classic.cartpole_pixels:CartPolePixels",
    "rl_jax/Pendulum-v1": "rl_jax.envs.classic.pendulum:Pendulum",
    "rl_jax/InvertedPendulum-v5": "rl_jax.envs.mujoco.inverted_pendulum:InvertedPendulum",
    "rl_jax/InvertedDoublePendulum-v5": (
        "rl_jax.envs.mujoco.inverted_double_pendulum:InvertedDoublePendulum"
    ),
    "rl_jax/HalfCheetah-v5": "rl_jax.envs.mujoco.half_cheetah:HalfCheetah",
    "rl_jax/Hopper-v5": "rl_jax.envs.mujoco.hopper:Hopper",
    "rl_jax/Ant-v5": "rl_jax.envs.mujoco.ant:Ant",
    "rl_jax/Humanoid-v5": "rl_jax.envs.mujoco.humanoid:Humanoid",
    "rl_jax/Walker2d-v5": "rl_jax.envs.mujoco.walker2d:Walker2d",
    "rl_jax/Swimmer-v5": "rl_jax.envs.mujoco.swimmer:Swimmer",
    "rl_jax/Reacher-v5": "rl_jax.envs.mujoco.reacher:Reacher",
    # partially observed: velocities hidden (envs/memory/masked.py says whose ids these are)
    "rl_jax/CartPoleNoVel-v1": "rl_jax.envs.memory.masked:cartpole_no_velocity",
    "rl_jax/PendulumNoVel-v1": "rl_jax.envs.memory.masked:pendulum_no_velocity",
    "rl_jax/Hopper-P-v5": "rl_jax.envs.memory.masked:hopper_positions",
    "rl_jax/Walker2d-P-v5": "rl_jax.envs.memory.masked:walker2d_positions",
    "rl_jax/HalfCheetah-P-v5": "rl_jax.envs.memory.masked:half_cheetah_positions",
    "rl_jax/Ant-P-v5": "rl_jax.envs.memory.masked:ant_positions",
    # POPGym's memory tasks at Easy
    "rl_jax/RepeatPreviousEasy-v0": "rl_jax.envs.memory.cards:RepeatPrevious",
    "rl_jax/RepeatFirstEasy-v0": "rl_jax.envs.memory.cards:RepeatFirst",
    "rl_jax/CountRecallEasy-v0": "rl_jax.envs.memory.cards:CountRecall",
    "rl_jax/AutoencodeEasy-v0": "rl_jax.envs.memory.cards:Autoencode",
    "rl_jax/StatelessCartPoleEasy-v0": "rl_jax.envs.memory.stateless_cartpole:StatelessCartPole",
    # MinAtar, gymnax's JAX games under gymnax's names (envs/adapters/gymnax_adapter.py)
    "rl_jax/Breakout-MinAtar": "rl_jax.envs.adapters.gymnax_adapter:breakout_minatar",
    "rl_jax/SpaceInvaders-MinAtar": "rl_jax.envs.adapters.gymnax_adapter:space_invaders_minatar",
    "rl_jax/Asterix-MinAtar": "rl_jax.envs.adapters.gymnax_adapter:asterix_minatar",
    "rl_jax/Freeway-MinAtar": "rl_jax.envs.adapters.gymnax_adapter:freeway_minatar",
    # Atari 2600 games through ale-py, with DQN's preprocessing (envs/adapters/atari.py)
    "rl_jax/Pong-Atari": "rl_jax.envs.adapters.atari:pong",
    "rl_jax/Breakout-Atari": "rl_jax.envs.adapters.atari:breakout",
    "rl_jax/SpaceInvaders-Atari": "rl_jax.envs.adapters.atari:space_invaders",
    "rl_jax/Seaquest-Atari": "rl_jax.envs.adapters.atari:seaquest",
}

#: The MinAtar games' ids: envs observed as 10x10xC grids of 0/1, which the learners see through
#: MinAtar's conv torso (their ``IMAGE_ENVS``).
MINATAR_IDS = tuple(
    f"rl_jax/{game}-MinAtar" for game in ("Breakout", "SpaceInvaders", "Asterix", "Freeway")
)

#: The Atari games' ids: envs observed as 4 stacked 84x84 frames, which the learners see through
#: a conv torso (their ``PIXEL_ENVS``); ``envs.from_atari`` makes any other ALE game.
ATARI_IDS = tuple(
    f"rl_jax/{game}-Atari" for game in ("Pong", "Breakout", "SpaceInvaders", "Seaquest")
)

# id -> episode limit, known without importing the env module: gymnasium's registration (its
# ``spec.max_episode_steps`` and TimeLimit) needs it before MuJoCo is imported. It must equal the
# env class's ``max_episode_steps`` (tests/envs/test_gym_adapter.py checks).
_MAX_EPISODE_STEPS: dict[str, int] = {
    "rl_jax/Rocket-v0": 500,
    "rl_jax/RocketSettle-v0": 500,
    "rl_jax/CartPole-v1": 500,
    "rl_jax/CartPolePixels-v1": 500,
    "rl_jax/Pendulum-v1": 200,
    "rl_jax/InvertedPendulum-v5": 1000,
    "rl_jax/InvertedDoublePendulum-v5": 1000,
    "rl_jax/HalfCheetah-v5": 1000,
    "rl_jax/Hopper-v5": 1000,
    "rl_jax/Ant-v5": 1000,
    "rl_jax/Humanoid-v5": 1000,
    "rl_jax/Walker2d-v5": 1000,
    "rl_jax/Swimmer-v5": 1000,
    "rl_jax/Reacher-v5": 50,
    "rl_jax/CartPoleNoVel-v1": 500,
    "rl_jax/PendulumNoVel-v1": 200,
    "rl_jax/Hopper-P-v5": 1000,
    "rl_jax/Walker2d-P-v5": 1000,
    "rl_jax/HalfCheetah-P-v5": 1000,
    "rl_jax/Ant-P-v5": 1000,
    # one step more than every episode lasts: they all end by termination (envs/memory/cards.py)
    "rl_jax/RepeatPreviousEasy-v0": 52,
    "rl_jax/RepeatFirstEasy-v0": 52,
    "rl_jax/CountRecallEasy-v0": 52,
    "rl_jax/AutoencodeEasy-v0": 104,
    "rl_jax/StatelessCartPoleEasy-v0": 200,
    # gymnax's max_steps_in_episode (Freeway's 2,500 is MinAtar's own end of its game)
    "rl_jax/Breakout-MinAtar": 1000,
    "rl_jax/SpaceInvaders-MinAtar": 1000,
    "rl_jax/Asterix-MinAtar": 1000,
    "rl_jax/Freeway-MinAtar": 2500,
    # ALE v5's 108,000 frames, in agent steps of 4 frames
    "rl_jax/Pong-Atari": 27000,
    "rl_jax/Breakout-Atari": 27000,
    "rl_jax/SpaceInvaders-Atari": 27000,
    "rl_jax/Seaquest-Atari": 27000,
}


class UnknownEnvError(ValueError):
    """Raised for a name that is not registered; the message lists the known ids."""


class EnvNotNamedError(UnknownEnvError):
    """An id that would import a module (``MODULE:ID``, or a gymnasium id that names one) where
    the caller allowed no imports: an id read from a run's records, which is data. ``module`` is
    the module the id would import; the caller asks the user to name the env again."""

    def __init__(self, env_id: str, module: str) -> None:
        super().__init__(
            f"environment {env_id!r} is defined in module {module!r}, which is imported only "
            "when you name the environment yourself"
        )
        self.env_id = env_id
        self.module = module


class UnsupportedEnvError(ValueError):
    """An env that exists but cannot be used as given (a gymnasium space the adapter does not
    translate, no time limit, missing extras); the message says what to change."""


class BackendError(ValueError):
    """Raised for an unknown MuJoCo backend name (``backend=`` or ``$RL_JAX_MUJOCO_BACKEND``);
    defined here, with the other user errors of env construction, so that reporting it does
    not import MuJoCo."""


def register(
    env_id: str,
    entry_point: str | Callable[..., Environment],
    max_episode_steps: int | None = None,
) -> None:
    """Add an env: ``entry_point`` is ``"package.module:Factory"`` (imported on first use) or the
    factory itself (an ``Environment`` class or a function returning one).

    ``max_episode_steps`` (optional) lets gymnasium's registration know the limit without
    importing the module; when omitted it is read from the env class on first use.
    """
    _ENTRY_POINTS[env_id] = entry_point
    if max_episode_steps is not None:
        _MAX_EPISODE_STEPS[env_id] = max_episode_steps


def registered_ids() -> list[str]:
    """Every env id ``envs.make`` knows, sorted."""
    return sorted(_ENTRY_POINTS)


# Set by envs.adapters.external_ids when rl_jax.envs is imported: it registers ``gymnasium:ID`` and
# ``MODULE:ID`` names on first use. A hook rather than an import, so that the core does not
# import the adapters that build on it.
_external_resolver: Callable[[str, bool], str] | None = None


def set_external_resolver(resolver: Callable[[str, bool], str]) -> None:
    """Let ``resolve_id`` hand names with a ``:`` to ``resolver(name, imports)`` (which
    registers them, importing a module only where ``imports`` allows it)."""
    global _external_resolver
    _external_resolver = resolver


def resolve_id(name: str, *, imports: bool = True) -> str:
    """Accept the full id (``rl_jax/Rocket-v0``) or the id without namespace, any case.

    ``imports=False`` resolves from what is registered alone (and gymnasium's own registry for
    ``gymnasium:ID``): a ``MODULE:ID`` that this process has not registered raises
    ``EnvNotNamedError`` instead of importing ``MODULE``. Ids read from a run's records are
    resolved so, since a record is data and must not choose code to run."""
    if name in _ENTRY_POINTS:
        return name
    wanted = name.lower().removeprefix("rl_jax/")
    for env_id in _ENTRY_POINTS:
        if env_id.lower().removeprefix("rl_jax/") == wanted:
            return env_id
    if ":" in name and _external_resolver is not None:  # "gymnasium:ID" or "MODULE:ID"
        return _external_resolver(name, imports)  # registered on first use
    known = ", ".join(registered_ids())
    raise UnknownEnvError(f"unknown environment {name!r}; known environments: {known}")


def names_a_module(env_id: str) -> bool:
    """Whether ``env_id`` imports a module of its own when it is resolved (``MODULE:ID``, or
    gymnasium's ``module:Env`` spelling): a run on it is opened with the env named again."""
    if env_id.startswith("gymnasium:"):
        return ":" in env_id.removeprefix("gymnasium:")
    return ":" in env_id


def factory(name: str) -> Callable[..., Environment]:
    """The class (or function) that builds the env; imports its module."""
    entry_point = _ENTRY_POINTS[resolve_id(name)]
    if callable(entry_point):
        return entry_point
    module_name, factory_name = entry_point.split(":")
    return getattr(importlib.import_module(module_name), factory_name)


def max_episode_steps(name: str) -> int:
    """The env's static episode limit, without importing its module when it is known."""
    env_id = resolve_id(name)
    if env_id not in _MAX_EPISODE_STEPS:
        # An Environment class has the limit; a function that builds one may not.
        limit = getattr(factory(env_id), "max_episode_steps", None)
        if limit is None:
            raise UnsupportedEnvError(
                f"environment {env_id!r} has no max_episode_steps on its factory: register it "
                "with max_episode_steps="
            )
        _MAX_EPISODE_STEPS[env_id] = int(limit)
    return _MAX_EPISODE_STEPS[env_id]


def parse_keywords(text: str) -> dict[str, Any]:
    """Constructor keywords written as in a call, ``"name=value, name=value"``: ``{name: value}``.

    Values are Python literals (``False``, ``0.1``, ``(-1.0, 1.0)``, ``'x.xml'``); a bare word
    that is not one is its own string (``backend=mjx``). ``""`` is no keywords. A ``ValueError``
    with one line says what is wrong. The training scripts' ``--env-kwargs`` is this text, kept
    as it was given in the run's config so that a resumed run or a loaded policy builds the same
    env."""
    if not text.strip():
        return {}
    try:
        call = ast.parse(f"f({text})", mode="eval").body
    except SyntaxError:
        raise ValueError(f"env keywords must read name=value, name=value; got {text!r}") from None
    if not isinstance(call, ast.Call) or call.args or any(k.arg is None for k in call.keywords):
        raise ValueError(f"env keywords must read name=value, name=value; got {text!r}")
    keywords: dict[str, Any] = {}
    for keyword in call.keywords:
        name = keyword.arg
        assert name is not None  # ``**mapping``, refused above
        if name in keywords:
            raise ValueError(f"env keyword {name!r} is given twice in {text!r}")
        if isinstance(keyword.value, ast.Name):
            keywords[name] = keyword.value.id
            continue
        try:
            keywords[name] = ast.literal_eval(keyword.value)
        except ValueError:
            value = ast.get_source_segment(f"f({text})", keyword.value)
            raise ValueError(
                f"env keyword {name}: {value} is not a Python literal (a number, "
                "True/False, a string or a tuple of them)"
            ) from None
    return keywords


def make(name: str, **kwargs: Any) -> Environment:
    """Build a registered env, e.g. ``envs.make("rl_jax/Rocket-v0")``."""
    env_id = resolve_id(name)
    env = factory(env_id)(**kwargs)
    env.id = env_id
    return env
