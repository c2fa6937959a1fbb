"""The interface every learner (ours and a user's own) offers to the run machinery: the
``Algorithm`` protocol and its ``OptionalHooks``.

Two kinds of settings, kept apart on purpose (the Rejax split):

* ``Config`` — a frozen dataclass of *static* settings: shapes, loop counts, network widths,
  buffer capacity, number of envs. Changing one recompiles. JSON-serialisable.
* ``Hyperparams`` — a ``flax.struct`` dataclass whose leaves are float/int *arrays*: learning
  rates, tau, gamma, noise scales, epsilon schedule. Stacking several along a leading axis and
  ``jax.vmap``-ing over them is a sweep inside one compiled program.

Everything a run needs to continue lives in the ``TrainState`` pytree (params, targets, optimizer
state, replay buffer, env state, last obs, PRNG key, counters), so a checkpoint of it is a resume.

The run machinery (experiments, sweeps, checkpoints, progress) only calls what is below; the
outermost ``jit`` and the seed/hyperparameter ``vmap`` are applied by ``rl_jax.training.parallel``.

A ``TrainState`` may have a field ``clock``: counters that depend only on the static ``Config``
(env steps, updates), identical in every seed and hyperparameter set. ``rl_jax.training.parallel``
keeps that one field unstacked (and replicated over devices), so learners can branch on it (warm-up,
delayed updates) with real branches under vmap; every other leaf gains the ``[H, S]`` axes.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable
from typing import (
    Any,
    ClassVar,
    Generic,
    NamedTuple,
    Protocol,
    Self,
    TypeAlias,
    TypeVar,
    runtime_checkable,
)

import jax
from flax import struct

from rl_jax import envs
from rl_jax.errors import RunError
from rl_jax.training.recipes import Recipe, Recipes, Setting

PRNGKey = jax.Array


class ChunkMetrics(NamedTuple):
    """What one compiled chunk reports for one seed (leaves gain [hparams, seeds] axes).

    ``extra`` holds algorithm-specific scalars (losses, q values, epsilon), each ``[]``.
    """

    env_steps: jax.Array  # [] int, total env steps taken so far (all envs of this seed)
    updates: jax.Array  # [] int, total gradient updates so far
    eval_return: jax.Array  # [] float32, mean undiscounted return of the deterministic policy
    train_return: jax.Array  # [] float32, mean return of training episodes finished so far
    extra: dict[str, jax.Array]


class Config(Protocol):
    """What the run machinery reads of any learner's static ``Config`` (a frozen dataclass: its
    fields read-only). ``num_envs`` and ``iterations_per_chunk`` serve the default of
    ``OptionalHooks.env_steps_per_chunk``: a learner that defines the hook need not have them."""

    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[Any]]]  # a dataclass: its fields

    @property
    def env_id(self) -> str: ...

    @property
    def num_envs(self) -> int: ...

    @property
    def iterations_per_chunk(self) -> int: ...


class Hyperparams(Protocol):
    """What it asks of any learner's ``Hyperparams`` (a ``flax.struct`` dataclass of arrays)."""

    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[Any]]]  # a dataclass: its fields

    def as_arrays(self) -> Self: ...

    def to_dict(self) -> dict[str, Any]: ...


class DataclassState(Protocol):
    """A train state that is a dataclass (``flax.struct.dataclass``)."""

    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[Any]]]


#: The pytree a learner keeps everything of one run in (``init`` makes it): a dataclass or a
#: NamedTuple of arrays. The run machinery does not read its fields, except an optional
#: ``clock`` (dataclass states; see above) and the ``policy_fields`` of the best policy.
TrainState: TypeAlias = DataclassState | tuple[object, ...]
#: ``obs -> action`` of a deterministic policy.
PolicyFn: TypeAlias = Callable[[jax.Array], jax.Array]
#: What a recurrent policy carries from one step of an episode to the next (one env's): a pytree
#: of arrays, e.g. an LSTM's ``(c, h)``.
PolicyState: TypeAlias = object
#: ``(policy_state, obs[, legal]) -> (action, policy_state)`` of a recurrent policy.
RecurrentPolicyFn: TypeAlias = Callable[..., tuple[jax.Array, PolicyState]]
#: ``(env_state, key) -> action`` of a planner that acts from its own env's state (a pgx
#: ``State``), not an observation: ``OptionalHooks.position_policy``.
PositionPolicyFn: TypeAlias = Callable[..., jax.Array]


class Algorithm(Protocol):
    """A learner. Implementations are plain modules or small stateless objects.

    Beyond the methods below, an algorithm may define the hooks of ``OptionalHooks`` (``HOOKS``
    names them); callers reach them through ``hooks(algorithm)``, which supplies the
    defaults."""

    name: str  # "td3", "ddpg", "td7", "crossq", "sac", "ppo", "dqn", "reinforce", or your own

    def default_config(self, env_id: str) -> Config:
        """The static ``Config`` for an env (its default recipe)."""

    def default_hyperparams(self, env_id: str | None = None) -> Hyperparams:
        """The ``Hyperparams`` pytree of scalars (the default recipe, for ``env_id`` if given:
        some envs need, e.g., another discount)."""

    def init(self, key: PRNGKey, config: Config, hparams: Hyperparams) -> TrainState:
        """A fresh ``TrainState`` for one seed and one hyperparameter set."""

    def train_chunk(
        self, state: TrainState, config: Config, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        """``config.iterations_per_chunk`` train iterations, then one evaluation. Pure."""

    def policy(self, state: TrainState, config: Config) -> PolicyFn:
        """A pure ``obs -> action`` function of the deterministic policy (for eval and GIFs);
        for a recurrent learner (``OptionalHooks.initial_policy_state``) a pure
        ``(policy_state, obs) -> (action, policy_state)``."""


@runtime_checkable
class MakesEnv(Protocol):
    """A config that builds its env itself (``make_env()``: the registered env with its
    keywords, or one adapted to the learner)."""

    def make_env(self) -> envs.Environment: ...


@runtime_checkable
class CountsEnvs(Protocol):
    """A config that says how many envs each seed steps together."""

    @property
    def num_envs(self) -> int: ...


@runtime_checkable
class DrawsBatches(Protocol):
    """A config that says how many transitions each gradient update draws."""

    @property
    def batch_size(self) -> int: ...


@runtime_checkable
class TakesEnvKeywords(Protocol):
    """A config that passes keywords to its registered env (``env_kwargs``: ``"name=value,..."``,
    ``rl_jax.envs.parse_keywords``)."""

    @property
    def env_kwargs(self) -> str: ...


@struct.dataclass
class Clock:
    """A train state's counters, which depend only on the config: every seed and hyperparameter
    set of a run shares them (kept unbatched by ``rl_jax.training.parallel``: ``SharesClock``)."""

    env_steps: jax.Array  # [] int32, env steps of one seed so far (all its envs)
    updates: jax.Array  # [] int32, gradient updates so far
    iterations: jax.Array  # [] int32


@runtime_checkable
class HoldsAgent(Protocol):
    """A train state whose ``agent`` holds what its policy reads (every built-in learner's):
    without a ``policy_fields`` hook, the best policy kept per seed is its ``agent``."""

    @property
    def agent(self) -> object: ...


@runtime_checkable
class SharesClock(Protocol):
    """A train state whose ``clock`` (the step counters) every seed of a run shares: kept
    unbatched and replicated rather than stacked per seed (``rl_jax.training.parallel``)."""

    @property
    def clock(self) -> object: ...


#: A learner's own ``Config`` type, in the hooks it defines.
ConfigT = TypeVar("ConfigT", bound=Config)


class OptionalHooks(Generic[ConfigT]):
    """The optional part of ``Algorithm``: what the run machinery asks of an algorithm beyond
    the protocol's methods, each with the default it gets when the algorithm does not define it.
    Shared code asks these, never a learner's config or state for a field by name.

    ``RecipeBook`` (and so every algorithm object here) inherits them. An algorithm written
    without this base (a plain module, an object of a class of its own) is seen through
    ``hooks(algorithm)``: its own hooks where it defines them, these defaults for the rest, so
    callers call ``hooks(algorithm).make_env(config)`` and never ask ``hasattr``. ``ConfigT``
    is the learner's ``Config``."""

    #: Train-state fields the deterministic policy reads (kept for the best-policy checkpoint).
    #: None: ``("agent",)`` when the state has that field, else no best-policy tracking.
    policy_fields: tuple[str, ...] | None = None
    #: ``validation.Range`` of config or hyperparameter fields, before the rules by name.
    ranges: dict[str, Any] = {}
    #: Named settings for envs (``rl_jax.training.recipes``). A learner with recipes takes
    #: ``recipe=NAME`` in ``default_config`` and ``default_hyperparams``; without, it is only
    #: ever asked for its defaults.
    recipes: Recipes = Recipes()

    def recipe(self, env_id: str, name: str | None = None) -> Recipe:
        """Recipe ``name`` (None: the env's default) for ``env_id``; ``KeyError`` if none."""
        return self.recipes.get(env_id, name)

    def env_steps_per_chunk(self, config: ConfigT) -> int:
        """Env steps one ``train_chunk`` takes per seed: ``num_envs * iterations_per_chunk``."""
        return int(config.num_envs * config.iterations_per_chunk)

    def validate(self, config: ConfigT, hparams: Hyperparams) -> None:
        """``ValueError`` for settings each valid alone that the algorithm cannot run together."""

    def owns_env(self, env_id: str) -> bool:
        """Whether the learner resolves ``env_id`` itself rather than through ``rl_jax.envs``
        (AlphaZero's ``pgx/GAME``). For such an id the run machinery keeps the id as given,
        never looks it up in the env registry and never steps the env: the learner's
        ``train_chunk`` evaluates inside the compiled program, ``load_policy`` gives a
        ``GamePolicy`` (``position_policy``), a GIF is games of that policy against the run's
        opponent (``rl_jax.run.render_game``), and gymnasium replays are refused in one line.
        Default: no id (every env is the registry's)."""
        return False

    def position_policy(self, state: TrainState, config: ConfigT) -> PositionPolicyFn | None:
        """For a learner that owns its env (``owns_env``): a pure ``(env_state, key) ->
        action`` of the trained planner, acting from the env's own state (a pgx ``State``: the
        search steps it) rather than an observation; the key may be fixed. Default: None."""
        return None

    def make_env(self, config: ConfigT) -> envs.Environment:
        """The env the policy acts in (loaded policies, rendering): the config's ``make_env()``
        where it has one (the registered ``env_id`` with its ``env_kwargs``), else ``env_id``.
        ``RunError`` for an env the learner owns: it is no ``rl_jax.envs`` env."""
        if self.owns_env(config.env_id):
            raise RunError(
                f"{config.env_id} is an env that the learner resolves itself, not one of "
                "rl_jax.envs, so the run tools cannot play episodes of it; measure the run with "
                "rl-jax match RUN_DIR, or play it with rl_jax.load_policy(RUN_DIR).move"
            )
        if isinstance(config, MakesEnv):
            return config.make_env()
        return envs.make(config.env_id)

    def envs_per_seed(self, config: ConfigT) -> int | None:
        """Envs each seed steps together, for the plan's line (None: the line does not say):
        the config's ``num_envs`` where it has one."""
        return config.num_envs if isinstance(config, CountsEnvs) else None

    def warm_up_steps(self, config: ConfigT) -> int:
        """Env steps per seed taken before the first gradient update (random actions, no
        learning): the time estimate measures a chunk past them. Default: none."""
        return 0

    def replay_capacity(self, config: ConfigT) -> int | None:
        """Transitions the replay buffer holds, as the config's ``buffer_size`` sets them (a
        state too big for memory is refused naming the ``--buffer-size`` that fits). Default:
        None, no replay buffer."""
        return None

    def replay_batch(self, config: ConfigT) -> int | None:
        """Transitions each update draws from the replay buffer, which must hold at least that
        many. Default: the config's ``batch_size`` where it has one, else None."""
        return config.batch_size if isinstance(config, DrawsBatches) else None

    def loop_seeds(self, config: ConfigT) -> bool:
        """Whether the seeds of a run go through the one program as an unrolled loop rather
        than a vmap (``rl_jax.training.parallel``: faster for conv nets on CPU). Default: no."""
        return False

    def initial_policy_state(self, config: ConfigT) -> PolicyState | None:
        """The state a recurrent policy starts each episode with, for one env (a pytree of
        arrays), or None (the default): the policy is feed-forward. Where it is not None, the
        learner's ``policy(state, config)`` maps ``(policy_state, obs[, legal])`` to
        ``(action, policy_state)``, and whoever acts (evaluation, GIFs, ``load_policy``) gives
        each env this state again at every episode start."""
        return None

    def defines_hook(self, name: str) -> bool:
        """Whether the algorithm defines the hook ``name`` itself rather than taking its
        default here."""
        _check_hook(name)
        if name in vars(self):
            return True
        owner = next(cls for cls in type(self).__mro__ if name in vars(cls))
        return owner is not OptionalHooks


HOOKS = (
    "policy_fields",
    "ranges",
    "recipes",
    "recipe",
    "env_steps_per_chunk",
    "validate",
    "owns_env",
    "position_policy",
    "make_env",
    "envs_per_seed",
    "warm_up_steps",
    "replay_capacity",
    "replay_batch",
    "loop_seeds",
    "initial_policy_state",
)


class _OwnHooks(OptionalHooks[Any]):
    """An algorithm without the ``OptionalHooks`` base seen through them: the hooks it defines
    itself, the defaults for the rest. Its members are read here, once, by listing them; the
    callers of ``hooks`` only ever see ``OptionalHooks``."""

    def __init__(self, algorithm: Algorithm) -> None:
        self._own = {name: value for name, value in inspect.getmembers(algorithm) if name in HOOKS}
        vars(self).update(self._own)

    def defines_hook(self, name: str) -> bool:
        _check_hook(name)
        return name in self._own


def _check_hook(name: str) -> None:
    if name not in HOOKS:
        raise ValueError(f"{name!r} is not an optional hook; they are {', '.join(HOOKS)}")


def hooks(algorithm: Algorithm) -> OptionalHooks[Any]:
    """The optional hooks of ``algorithm``: its own where it defines them, else the defaults."""
    if isinstance(algorithm, OptionalHooks):
        return algorithm
    return _OwnHooks(algorithm)


class RecipeBook(OptionalHooks[ConfigT]):
    """What the algorithm objects share: settings from the learner's defaults, then one of its
    ``recipes`` (``rl_jax.training.recipes``: ``"default"`` unless a name is given), then the
    caller's overrides.

    Subclasses set ``name``, ``config_type`` (``ConfigT``), ``hparams_type`` (with
    ``as_arrays()``) and ``recipes``.
    """

    name: str
    config_type: type
    hparams_type: type

    def default_config(
        self, env_id: str, recipe: str | None = None, **overrides: Setting
    ) -> ConfigT:
        values = {**self.recipe(env_id, recipe).config, **overrides}
        return self.config_type(env_id=env_id, **values)

    def default_hyperparams(
        self,
        env_id: str | None = None,
        recipe: str | None = None,
        **overrides: Setting | jax.Array,
    ) -> Hyperparams:
        values = self.recipe(env_id, recipe).hparams if env_id else {}
        return self.hparams_type(**{**values, **overrides}).as_arrays()

    def __repr__(self) -> str:
        return f"<algorithm {self.name}>"
