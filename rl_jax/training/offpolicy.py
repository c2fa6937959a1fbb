"""The off-policy training loop shared by TD3, DDPG, TD7, CrossQ, SAC, DQN and R2D2.

One *iteration*: all ``num_envs`` envs act (uniformly random for the first ``learning_starts`` env
steps, then the learner's exploration policy) and step once, the ``num_envs`` transitions go into
the replay buffer as one row, then ``updates_per_iteration`` gradient updates run. A *chunk* is
``iterations_per_chunk`` iterations under ``lax.scan`` followed by one evaluation of the
deterministic policy on separate env copies, so one compiled call does thousands of env steps and
updates, and evaluation happens at a fixed interval inside the same program.

A learner plugs in through ``Learner``: how to build its ``agent`` pytree (parameters, targets,
optimizer states), how to act, and one gradient update. Everything else is here.

``TrainState.clock`` holds counters that depend only on the static config (never on the seed or
hyperparameters), so ``rl_jax.training.parallel`` keeps it unbatched: branching on it (warm-up,
delayed policy updates) then stays a real branch under the seed/hyperparameter vmap instead of
running both sides.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, NamedTuple, Self, TypeAlias, TypeVar, cast

import jax
import jax.numpy as jnp
from flax import struct
from flax.typing import ArrayPytree

from rl_jax import envs
from rl_jax.envs.core.wrappers import ACTION_MASK, FINAL_ACTION_MASK, StatisticsState
from rl_jax.training import replay
from rl_jax.training.algorithm import ChunkMetrics, Clock, Hyperparams, PolicyFn, RecipeBook
from rl_jax.training.episodes import (
    batched_policy_state,
    evaluate,
    evaluate_recurrent,
    example_transition,
    make_eval_env,
    make_train_env,
    mean_return,
    reset_policy_state,
)
from rl_jax.training.replay import ReplayBuffer, Transition

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

PRNGKey = jax.Array
#: One update's metrics by name, each [] float32.
Metrics = dict[str, jax.Array]


@dataclasses.dataclass(frozen=True, kw_only=True)
class OffPolicyConfig:
    """Static settings of the loop (changing one recompiles). Learners subclass it."""

    env_id: str
    num_envs: int = 1  # envs stepped together; each iteration adds num_envs transitions
    updates_per_iteration: int = 1  # gradient updates after each env step of all envs
    iterations_per_chunk: int = 5000  # per compiled call; eval after each (paper: every 5,000)
    batch_size: int = 256  # transitions per gradient update
    buffer_size: int = 1_000_000  # transitions (rounded up to a multiple of num_envs)
    learning_starts: int = 25_000  # env steps (all envs) with random actions and no updates
    num_eval_envs: int = 10  # episodes of the deterministic policy per evaluation
    # the env's constructor keywords, "name=value, name=value" (e.g.
    # "include_cfrc_ext_in_observation=False"): envs.make(env_id, **them) for training,
    # evaluation and loaded policies; the recipe is still env_id's
    env_kwargs: str = ""

    def __post_init__(self) -> None:
        envs.parse_keywords(self.env_kwargs)  # a ValueError names what is wrong
        counts = {
            "num_envs": self.num_envs,
            "updates_per_iteration": self.updates_per_iteration,
            "iterations_per_chunk": self.iterations_per_chunk,
            "batch_size": self.batch_size,
            "buffer_size": self.buffer_size,
            "num_eval_envs": self.num_eval_envs,
        }
        for name, value in counts.items():
            if value < 1:
                raise ValueError(f"{name} must be >= 1, got {value}")
        if self.learning_starts < 0:
            raise ValueError(f"learning_starts must be >= 0, got {self.learning_starts}")

    @property
    def env_steps_per_chunk(self) -> int:
        """Env steps (over all envs) one compiled chunk takes."""
        return self.num_envs * self.iterations_per_chunk

    def make_env(self) -> envs.Environment:
        """The env as registered, with ``env_kwargs``; learners that adapt it (e.g. discretise
        actions) override."""
        return envs.make(self.env_id, **envs.parse_keywords(self.env_kwargs))

    def to_dict(self) -> dict[str, object]:
        """The config's fields as a dict."""
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        """The config as one JSON string with sorted keys."""
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> Self:
        """Inverse of ``to_dict`` (JSON lists become tuples again); unknown keys are an error."""
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - set(fields))
        if unknown:
            raise ValueError(f"unknown {cls.__name__} field(s): {', '.join(unknown)}")
        tuples = {k: tuple(v) for k, v in values.items() if isinstance(v, list)}
        return cls(**{**values, **tuples})


#: What the loop carries per env between steps for a learner's exploration: its noise
#: ``[num_envs, *action_shape]``, or a recurrent learner's policy state (an LSTM's ``(c, h)``).
ExplorationState: TypeAlias = jax.Array | tuple[jax.Array, ...]


@struct.dataclass
class TrainState:
    """Everything a run needs to continue; only arrays (checkpointable as is)."""

    agent: ArrayPytree  # the learner's parameters, targets and optimizer states
    buffer: ReplayBuffer  # of Transition, leaves [rows, num_envs, ...]
    env_state: StatisticsState  # [num_envs, ...] of the train env (make_train_env)
    obs: jax.Array  # [num_envs, *obs_shape], the observation the next action answers
    # [num_envs, *action_shape] float32, exploration state (see Learner); for a recurrent
    # learner (Learner.policy_state) each env's policy state, a pytree with leading axis num_envs
    noise: ExplorationState
    key: PRNGKey
    clock: Clock
    train_return: jax.Array  # [] float32, mean return of the episodes ended in the last chunk
    #                           that ended any (NaN until one does)
    # [num_envs, A] bool, the legal actions of obs, for an env with an action mask (else None:
    # no leaf, so the states of other envs stay as they were)
    action_mask: jax.Array | None = None


#: The learner's own types: its agent pytree, replay memory, ``Config`` and ``Hyperparams``.
AgentT = TypeVar("AgentT")
BufferT = TypeVar("BufferT")
ConfigT = TypeVar("ConfigT", bound=OffPolicyConfig)
HparamsT = TypeVar("HparamsT")


def uniform_buffer(example: Transition, config: OffPolicyConfig) -> ReplayBuffer[Transition]:
    return replay.init(example, config.buffer_size, config.num_envs)


def add_uniform(
    buffer: ReplayBuffer[Transition],
    transitions: Transition,
    config: OffPolicyConfig,
    hparams: object,
) -> ReplayBuffer[Transition]:
    return replay.add(buffer, transitions)


class Learner(NamedTuple, Generic[AgentT, BufferT, ConfigT, HparamsT]):
    """What an off-policy algorithm provides. ``config``/``hparams`` are its own types.

    init_agent(key, config, hparams, obs_space, action_space) -> agent
    explore(agent, obs [N, ...], noise [N, ...], key, config, hparams, clock)
        -> (actions [N, ...], noise): acting after warm-up. ``noise`` is per-env exploration
        state carried from step to step (temporally correlated exploration; zeroed when an
        episode ends); ``clock`` lets a schedule, e.g. epsilon, depend on progress. For an env
        with a legal-action mask it is also given ``legal=`` (bool ``[N, A]``, of ``obs``).
    act(agent, obs [N, ...], config) -> deterministic actions [N, ...]; for an env with an
        action mask, ``act(agent, obs, config, legal)``.
    update(agent, buffer, key, config, hparams, update_index []) -> (agent, buffer, metrics)
        one gradient update (it samples the buffer itself, so prioritised replay can write
        priorities back); ``update_index`` counts updates before this one (unbatched);
        ``metrics`` is a dict of [] float32, NaN where a quantity was not computed this update.
    metric_names: the keys of ``metrics``, or a function of the config giving them (when an
        option adds some).
    init_buffer(example_transition, config) -> buffer, and
    add_to_buffer(buffer, transitions [N, ...], config, hparams) -> buffer
        (optional) the replay memory; default: ``rl_jax.training.replay``'s uniform circular buffer.
    observe(agent, transitions [N, ...], episode_return [N], done [N], clock, config, hparams)
        -> agent (optional): what the learner keeps of every env step besides the replay, before
        this iteration's updates (running observation statistics, returns of ended episodes:
        ``episode_return`` counts where ``done``); ``clock`` is before the step. None: nothing.
    policy_state(config) -> one env's policy state at an episode start (optional): set, the
        learner is recurrent. Its ``noise`` is then that state, carried by ``explore`` (also while
        warming up, whose random actions do not replace it) and reset to this at episode starts;
        each transition keeps the state its action was chosen with (``Transition.policy_state``,
        stored-state replay); ``act`` is ``act(agent, policy_state [N, ...], obs [N, ...],
        config) -> (actions, policy_state)``, evaluated with ``episodes.evaluate_recurrent``.
    """

    init_agent: Callable[[PRNGKey, ConfigT, HparamsT, envs.Space, envs.Space], AgentT]
    explore: Callable[
        [AgentT, jax.Array, ArrayPytree, PRNGKey, ConfigT, HparamsT, Clock],
        tuple[jax.Array, ArrayPytree],
    ]
    act: Callable[[AgentT, jax.Array, ConfigT], jax.Array]
    update: Callable[
        [AgentT, BufferT, PRNGKey, ConfigT, HparamsT, jax.Array],
        tuple[AgentT, BufferT, dict[str, jax.Array]],
    ]
    metric_names: tuple[str, ...] | Callable[[ConfigT], tuple[str, ...]]
    # The defaults hold for BufferT = ReplayBuffer[Transition] only: a default of a generic
    # NamedTuple cannot say so, and a learner that keeps them gets that BufferT.
    init_buffer: Callable[[Transition, ConfigT], BufferT] = uniform_buffer  # type: ignore[assignment]
    add_to_buffer: Callable[[BufferT, Transition, ConfigT, HparamsT], BufferT] = add_uniform  # type: ignore[assignment]
    observe: (
        Callable[[AgentT, Transition, jax.Array, jax.Array, Clock, ConfigT, HparamsT], AgentT]
        | None
    ) = None
    policy_state: Callable[[ConfigT], ExplorationState] | None = None


def buffer_nbytes(config: OffPolicyConfig) -> int:
    """Replay memory of one run (one seed, one hyperparameter set), without allocating it."""
    example = example_transition(make_eval_env(config))
    return replay.nbytes(example, config.buffer_size, config.num_envs)


# ---- init ---------------------------------------------------------------------------------------
def init(
    learner: Learner, key: PRNGKey, config: OffPolicyConfig, hparams: DataclassInstance
) -> TrainState:
    """A fresh state for one seed and one hyperparameter set."""
    env = make_train_env(config)
    agent_key, env_key, key = jax.random.split(key, 3)
    env_state, timestep = jax.vmap(env.reset)(jax.random.split(env_key, config.num_envs))
    agent = learner.init_agent(
        agent_key, config, hparams, env.observation_space(), env.action_space()
    )
    buffer = learner.init_buffer(example_transition(env), config)
    zero = jnp.int32(0)
    noise: ExplorationState = jnp.zeros((config.num_envs, *env.action_space().shape), jnp.float32)
    if learner.policy_state is not None:
        initial = learner.policy_state(config)
        noise = cast(ExplorationState, batched_policy_state(initial, config.num_envs))
    return TrainState(
        agent=agent,
        buffer=buffer,
        env_state=env_state,
        obs=timestep.obs,
        noise=noise,
        key=key,
        clock=Clock(env_steps=zero, updates=zero, iterations=zero),
        train_return=jnp.float32(jnp.nan),
        action_mask=timestep.info[ACTION_MASK] if envs.has_action_mask(env) else None,
    )


# ---- one iteration -----------------------------------------------------------------------------
def random_actions(space: envs.Space, key: PRNGKey, count: int) -> jax.Array:
    return jax.vmap(space.sample)(jax.random.split(key, count))


def _choose_actions(
    learner: Learner,
    config: OffPolicyConfig,
    hparams: DataclassInstance,
    state: TrainState,
    key: PRNGKey,
    space: envs.Space,
) -> tuple[jax.Array, ExplorationState]:
    """``(actions, noise)``: uniformly random while warming up, then the learner's choice
    (over the legal actions only, for an env with an action mask)."""
    warming_up = state.clock.env_steps < config.learning_starts
    legal = state.action_mask
    if learner.policy_state is not None:  # the state follows the episode from its first step
        choose = lambda: learner.explore(  # noqa: E731
            state.agent, state.obs, state.noise, key, config, hparams, state.clock
        )
        return jax.lax.cond(
            warming_up,
            lambda: (random_actions(space, key, config.num_envs), choose()[1]),
            choose,
        )
    if legal is None:
        return jax.lax.cond(
            warming_up,
            lambda: (random_actions(space, key, config.num_envs), state.noise),
            lambda: learner.explore(
                state.agent, state.obs, state.noise, key, config, hparams, state.clock
            ),
        )
    explore: Callable[..., tuple[jax.Array, jax.Array]] = learner.explore
    uniform_legal = jnp.where(legal, 0.0, -jnp.inf)
    return jax.lax.cond(
        warming_up,
        lambda: (jax.random.categorical(key, uniform_legal).astype(jnp.int32), state.noise),
        lambda: explore(
            state.agent, state.obs, state.noise, key, config, hparams, state.clock, legal=legal
        ),
    )


def _updates(
    learner: Learner,
    config: OffPolicyConfig,
    hparams: DataclassInstance,
    state: TrainState,
    key: PRNGKey,
    buffer: ReplayBuffer,
) -> tuple[ArrayPytree, ReplayBuffer, dict[str, jax.Array], jax.Array]:
    """``updates_per_iteration`` updates, or none (NaN metrics) while warming up."""
    count = config.updates_per_iteration

    def run(agent: object, buffer: ReplayBuffer) -> tuple[object, ReplayBuffer, Metrics]:
        def one(
            carry: tuple[object, ReplayBuffer], inputs: tuple[jax.Array, jax.Array]
        ) -> tuple[tuple[object, ReplayBuffer], Metrics]:
            update_key, index = inputs
            agent, buffer, metrics = learner.update(*carry, update_key, config, hparams, index)
            return (agent, buffer), metrics

        inputs = (jax.random.split(key, count), state.clock.updates + jnp.arange(count))
        (agent, buffer), metrics = jax.lax.scan(one, (agent, buffer), inputs)
        return agent, buffer, jax.tree.map(jnp.nanmean, metrics)

    def skip(agent: object, buffer: ReplayBuffer) -> tuple[object, ReplayBuffer, Metrics]:
        nan = jnp.full((), jnp.nan, jnp.float32)
        names = learner.metric_names
        names = names(config) if callable(names) else names
        return agent, buffer, {name: nan for name in names}

    learning = state.clock.env_steps >= config.learning_starts
    agent, buffer, metrics = jax.lax.cond(learning, run, skip, state.agent, buffer)
    return agent, buffer, metrics, jnp.where(learning, count, 0)


def train_iteration(
    learner: Learner, config: OffPolicyConfig, hparams: DataclassInstance, state: TrainState
) -> tuple[TrainState, tuple[dict[str, jax.Array], tuple[jax.Array, jax.Array]]]:
    """All envs act and step once, the transitions are stored, then the gradient updates."""
    env = make_train_env(config)
    key, act_key, step_key, update_key = jax.random.split(state.key, 4)
    actions, noise = _choose_actions(learner, config, hparams, state, act_key, env.action_space())
    step_keys = jax.random.split(step_key, config.num_envs)
    env_state, ts = jax.vmap(env.step)(step_keys, state.env_state, actions)
    transition = Transition(
        state.obs, actions, ts.reward, ts.info["final_obs"], ts.terminated, ts.truncated
    )
    if state.action_mask is not None:
        transition = transition._replace(next_legal=ts.info[FINAL_ACTION_MASK])
    if learner.policy_state is not None:
        transition = transition._replace(policy_state=state.noise)
    buffer = learner.add_to_buffer(state.buffer, transition, config, hparams)
    done = jnp.logical_or(ts.terminated, ts.truncated)
    if learner.observe is not None:
        agent = learner.observe(
            state.agent, transition, ts.info["episode_return"], done, state.clock, config, hparams
        )
        state = dataclasses.replace(state, agent=agent)
    agent, buffer, metrics, updates = _updates(learner, config, hparams, state, update_key, buffer)
    if learner.policy_state is None:
        array = cast(jax.Array, noise)  # a noise array: no policy state
        noise = jnp.where(jnp.reshape(done, done.shape + (1,) * (array.ndim - 1)), 0.0, array)
    else:
        noise = reset_policy_state(done, noise, learner.policy_state(config))
    clock = Clock(
        env_steps=state.clock.env_steps + config.num_envs,
        updates=state.clock.updates + updates,
        iterations=state.clock.iterations + 1,
    )
    state = dataclasses.replace(
        state,
        agent=agent,
        buffer=buffer,
        env_state=env_state,
        obs=ts.obs,
        noise=noise,
        key=key,
        clock=clock,
    )
    if state.action_mask is not None:
        state = dataclasses.replace(state, action_mask=ts.info[ACTION_MASK])
    episodes = (jnp.sum(jnp.where(done, ts.info["episode_return"], 0.0)), jnp.sum(done))
    return state, (metrics, episodes)


def env_steps_at_update(update_index: jax.Array, config: OffPolicyConfig) -> jax.Array:
    """Env steps taken (all envs, this one included) in the iteration that runs update number
    ``update_index`` (0-based): updates start in the first iteration that begins with at least
    ``learning_starts`` steps taken, ``updates_per_iteration`` per iteration. Lets an update-side
    schedule (e.g. prioritized replay's beta) run on env steps, like exploration."""
    first_iteration = -(-config.learning_starts // config.num_envs)
    iteration = first_iteration + update_index // config.updates_per_iteration
    return (iteration + 1) * config.num_envs


# ---- a chunk ------------------------------------------------------------------------------------
def train_chunk(
    learner: Learner, state: TrainState, config: OffPolicyConfig, hparams: DataclassInstance
) -> tuple[TrainState, ChunkMetrics]:
    """``config.iterations_per_chunk`` iterations, then one evaluation. Pure; jit it outside."""

    def body(
        state: TrainState, _: None
    ) -> tuple[TrainState, tuple[Metrics, tuple[jax.Array, jax.Array]]]:
        return train_iteration(learner, config, hparams, state)

    state, (metrics, (return_sums, episode_counts)) = jax.lax.scan(
        body, state, None, length=config.iterations_per_chunk
    )
    eval_key, key = jax.random.split(state.key)
    if learner.policy_state is None:
        eval_return = evaluate(learner.act, state.agent, config, eval_key)
    else:
        initial = learner.policy_state(config)
        act: Callable[..., tuple[jax.Array, ExplorationState]] = learner.act  # type: ignore[assignment]
        eval_return = evaluate_recurrent(act, initial, state.agent, config, eval_key)
    train_return = mean_return(return_sums, episode_counts, state.train_return)
    state = dataclasses.replace(state, key=key, train_return=train_return)
    chunk_metrics = ChunkMetrics(
        env_steps=state.clock.env_steps,
        updates=state.clock.updates,
        eval_return=eval_return,
        train_return=train_return,
        extra=jax.tree.map(jnp.nanmean, metrics),
    )
    return state, chunk_metrics


# ---- the Algorithm object -----------------------------------------------------------------------
class OffPolicyAlgorithm(RecipeBook[ConfigT]):
    """What every learner on this loop offers the run machinery beyond its settings: ``init``,
    ``train_chunk`` and a ``policy`` that acts with ``learner.act`` on a seed's agent.

    ``ConfigT`` is the learner's ``Config``. Subclasses set ``learner`` besides ``RecipeBook``'s
    ``name``, ``config_type``, ``hparams_type`` and ``recipes``."""

    learner: Learner

    def init(self, key: PRNGKey, config: ConfigT, hparams: Hyperparams) -> TrainState:
        """A fresh ``TrainState`` for one seed and one hyperparameter set."""
        return init(self.learner, key, config, hparams)

    def train_chunk(
        self, state: TrainState, config: ConfigT, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        """``config.iterations_per_chunk`` iterations, then one evaluation. Pure."""
        return train_chunk(self.learner, state, config, hparams)

    def policy(self, state: TrainState, config: ConfigT) -> PolicyFn:
        """``obs -> action`` (env units) of the deterministic policy of one seed's state; for an
        env with an action mask, ``(obs, legal) -> action``, a legal one."""
        agent, act = state.agent, self.learner.act
        act_legal: Callable[..., jax.Array] = act

        def policy(obs: jax.Array, legal: jax.Array | None = None) -> jax.Array:
            if legal is None:
                return act(agent, obs, config)
            return act_legal(agent, obs, config, legal)

        return policy

    def warm_up_steps(self, config: ConfigT) -> int:
        """The config's ``learning_starts``: env steps of random actions before any update."""
        return config.learning_starts

    def replay_capacity(self, config: ConfigT) -> int:
        """The config's ``buffer_size``, in transitions."""
        return config.buffer_size
