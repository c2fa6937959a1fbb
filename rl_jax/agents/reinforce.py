"""REINFORCE (Williams 1992): Monte-Carlo policy gradient on whole episodes.

Each *iteration* resets ``num_envs`` vmapped envs, runs them to the end of every episode (up to
the env's step limit; a mask is 0 from the step after each episode's end on, and finished envs
are frozen), then takes one AdamW step on

    loss = -1/N sum_episodes sum_t log pi(a_t | s_t) (G_t - b_t)  [+ value_coef * value loss]

with the discounted reward-to-go ``G_t = sum_{k>=t} gamma^(k-t) r_k`` (masked). Options:
``normalize_returns`` (standardise ``G`` over the batch's valid steps) and ``baseline``: ``"none"``,
``"mean"`` (the batch mean of ``G``) or ``"value"`` (a learned state-value head on the policy's
torso, trained by squared error to ``G``; the advantage does not differentiate through it).

Policies (``rl_jax.training.networks.StochasticPolicy``): a diagonal Gaussian for ``Box`` actions,
with mean and state-dependent std heads, ``std = softplus(raw) + std_floor`` (the floor is on the
std, so the density stays finite; the mean is untouched); the sampled action is clipped to the
bounds for the env step, its log-probability is that of the unclipped sample. A categorical policy
for ``Discrete`` actions. Evaluation acts with the mean (clipped) or the most likely action.

The default network is the one of gymnasium's REINFORCE tutorial for the inverted pendulum: tanh
layers of 16 and 32 units, AdamW; ``hidden`` takes deeper nets. A truncated episode is treated as
ended (no bootstrap): REINFORCE has no critic to bootstrap from.

Env steps. Episodes end at different times in every seed, but the run machinery (plans, curves
over seeds, results) needs one step axis shared by all seeds. So ``ChunkMetrics.env_steps`` (the
logged ``step``, ``--total-steps``) counts env step *slots*: ``num_envs * max_episode_steps`` per
update, the most a batch can take (exact once episodes run to the time limit, an overcount while
they end early). The real count of env steps inside episodes is logged as ``env_steps_taken``.

Here: its settings (``Config``, ``Hyperparams``), its policy network, the loss and update, its
recipes per env and the learner object. Beside it: the policy's outputs, sampling and the
episodes it collects (``reinforce_parts``) and its pure maths (``policy_gradient``).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.typing import ArrayLike

from rl_jax import envs
from rl_jax.agents import reinforce_parts
from rl_jax.agents.common import clip_by_global_norm, injected_step, linearly_decayed
from rl_jax.agents.policy_gradient import (
    entropy,
    log_prob,
    normalize,
    policy_gradient_loss,
    reward_to_go,
)
from rl_jax.agents.reinforce_parts import Trajectory, to_env_action
from rl_jax.training import episodes, networks, normalization, params
from rl_jax.training.algorithm import ChunkMetrics, RecipeBook
from rl_jax.training.recipes import Recipe, Recipes, Setting

# ---- settings -------------------------------------------------------------------------------
BASELINES = ("none", "mean", "value")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config:
    """Static settings of REINFORCE (changing one recompiles)."""

    env_id: str
    num_envs: int = 16  # episodes per update, collected by vmapped envs
    iterations_per_chunk: int = 20  # updates per compiled call; eval after each chunk
    num_eval_envs: int = 10  # episodes of the deterministic policy per evaluation
    hidden: tuple[int, ...] = (16, 32)  # the policy's torso
    activation: networks.Activation = "tanh"  # see rl_jax.training.networks.ACTIVATIONS
    baseline: str = "none"  # "none", "mean" (batch mean of returns) or "value" (learned)
    normalize_returns: bool = False  # standardise the returns over each batch
    std_floor: float = 1e-6  # Gaussian policy: the std's lower bound
    std_mode: networks.StdMode = "state"  # Gaussian std: "state" (a head) or "param" (state-free)
    initial_std: float = 1.0  # with std_mode "param": the std before training
    value_hidden: tuple[int, ...] = ()  # baseline "value": its own torso (empty: shares policy's)
    normalize_obs: bool = False  # standardise observations by running mean and variance
    network_init: networks.Initializer = "fan_in_uniform"  # see rl_jax.training.networks
    squash_mean: bool = False  # Gaussian policy: the mean is tanh-squashed into the action bounds
    # the env's constructor keywords, "name=value, name=value": envs.make(env_id, **them)
    env_kwargs: str = ""

    def __post_init__(self) -> None:
        envs.parse_keywords(self.env_kwargs)  # a ValueError names what is wrong
        for name in ("num_envs", "iterations_per_chunk", "num_eval_envs"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.baseline not in BASELINES:
            raise ValueError(f"baseline must be one of {BASELINES}, got {self.baseline!r}")
        if self.activation not in networks.ACTIVATIONS:
            raise ValueError(f"activation must be one of {list(networks.ACTIVATIONS)}")
        if self.std_mode not in ("state", "param"):
            raise ValueError(f"std_mode must be 'state' or 'param', got {self.std_mode!r}")
        if self.initial_std <= 0.0:
            raise ValueError(f"initial_std must be > 0, got {self.initial_std}")
        if self.std_floor <= 0.0:
            raise ValueError(f"std_floor must be > 0, got {self.std_floor}")
        if self.network_init not in networks.INITS:
            raise ValueError(f"network_init must be one of {networks.INITS}")

    def make_env(self) -> envs.Environment:
        """The registered env, built with ``env_kwargs``."""
        return envs.make(self.env_id, **envs.parse_keywords(self.env_kwargs))


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: gymnasium's REINFORCE tutorial."""

    learning_rate: ArrayLike = 1e-4  # AdamW step size
    weight_decay: ArrayLike = 0.01  # AdamW's decoupled weight decay (torch's default)
    gamma: ArrayLike = 0.99  # discount of the reward-to-go
    value_coef: ArrayLike = 0.5  # weight of the value head's loss (baseline "value")
    entropy_coef: ArrayLike = 0.0  # weight of the policy's mean entropy, subtracted from the loss
    max_grad_norm: ArrayLike = 0.0  # clip the gradient's global norm to this (0: no clipping)
    lr_decay_updates: ArrayLike = 0.0  # updates for the rate to fall linearly to 0 (0: constant)


# ---- the policy network (reinforce_parts) ---------------------------------------------------
@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> networks.StochasticPolicy:
    """The policy network (with a value head for ``baseline="value"``) for ``config``
    (cached: called at every trace)."""
    space = episodes.action_space(config)
    discrete = isinstance(space, envs.Discrete)
    layers = networks.Layers(
        hidden=config.hidden, activation=config.activation, initializer=config.network_init
    )
    return networks.StochasticPolicy(
        layers=layers,
        action_dim=1 if discrete else space.shape[0],
        num_actions=space.n if isinstance(space, envs.Discrete) else None,
        std_floor=config.std_floor,
        value=config.baseline == "value",
        std_mode=config.std_mode,
        initial_std=config.initial_std,
        value_hidden=config.value_hidden,
    )


def policy_outputs(
    params: optax.Params,
    obs_stats: normalization.RunningStats | None,
    obs: jax.Array,
    config: Config,
) -> dict[str, jax.Array]:
    """The network's outputs on (standardised, when there are statistics) observations; with
    ``squash_mean`` the Gaussian's mean inside the action bounds
    (``reinforce_parts.policy_outputs``)."""
    space = episodes.action_space(config) if config.squash_mean else None
    squash_into = space if isinstance(space, envs.Box) else None
    return reinforce_parts.policy_outputs(make_network(config), params, obs_stats, obs, squash_into)


def rollout(
    params: optax.Params,
    key: jax.Array,
    config: Config,
    obs_stats: normalization.RunningStats | None = None,
    env: envs.Environment | None = None,
) -> Trajectory:
    """``num_envs`` whole episodes, stopping as soon as all have ended (raw observations are
    stored; the policy acts on them standardised by ``obs_stats`` when given). ``env``: the env
    to run instead of the config's (as ``episodes.make_eval_env`` builds it)."""
    env = episodes.make_eval_env(config) if env is None else env
    policy_of = lambda obs: policy_outputs(params, obs_stats, obs, config)  # noqa: E731
    return reinforce_parts.run_episodes(policy_of, key, env, config.num_envs)


# ---- state ----------------------------------------------------------------------------------
@struct.dataclass
class Agent:
    """Policy parameters, the optimizer state and, with ``normalize_obs``, observation
    statistics."""

    params: optax.Params  # policy (and value head) parameters
    opt_state: optax.InjectStatefulHyperparamsState  # adamw's: holds the rates in use
    obs_stats: normalization.RunningStats | None = None  # with normalize_obs, else None


@struct.dataclass
class Clock:
    """Counters that depend only on the config (kept unbatched by ``rl_jax.training.parallel``)."""

    updates: jax.Array  # [] int32


@struct.dataclass
class TrainState:
    """One seed's training state: the agent, its key and counts."""

    agent: Agent
    key: jax.Array
    clock: Clock
    env_steps: jax.Array  # [] int32, real env steps so far (episodes differ in length per seed)
    train_return: jax.Array  # [] float32, mean return of the last batch of episodes


# ---- the loss -------------------------------------------------------------------------------
def loss_fn(
    params: optax.Params,
    trajectory: Trajectory,
    hparams: Hyperparams,
    config: Config,
    obs_stats: normalization.RunningStats | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(loss, metrics)`` of one batch of whole episodes (``obs_stats``: the statistics the
    episodes were collected with, ``None`` without observation normalisation)."""
    policy = policy_outputs(params, obs_stats, trajectory.obs, config)
    mask = trajectory.mask
    returns = reward_to_go(trajectory.reward, mask, hparams.gamma)
    if config.normalize_returns:
        returns = normalize(returns, mask)
    count = jnp.maximum(jnp.sum(mask), 1.0)
    value_loss = jnp.float32(0.0)
    if config.baseline == "mean":
        advantage = returns - jnp.sum(returns * mask) / count
    elif config.baseline == "value":
        advantage = returns - policy["value"]
        value_loss = jnp.sum(mask * (policy["value"] - returns) ** 2) / count
    else:
        advantage = returns
    loss = policy_gradient_loss(log_prob(policy, trajectory.action), advantage, mask)
    mean_entropy = jnp.sum(mask * entropy(policy)) / count
    total = loss + hparams.value_coef * value_loss - hparams.entropy_coef * mean_entropy
    return total, {"loss": loss, "value_loss": value_loss, "entropy": mean_entropy}


# ---- acting and rollouts --------------------------------------------------------------------
def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The deterministic policy: the Gaussian's mean (clipped) or the most likely action."""
    policy = policy_outputs(agent.params, agent.obs_stats, obs, config)
    if "logits" in policy:
        return jnp.argmax(policy["logits"], axis=-1).astype(jnp.int32)
    space = episodes.action_space(config)
    return to_env_action(policy["mean"], space)


# ---- training -------------------------------------------------------------------------------
def _adamw(learning_rate: ArrayLike, weight_decay: ArrayLike) -> optax.GradientTransformation:
    return optax.adamw(learning_rate, weight_decay=weight_decay)


def learning_rate(hparams: Hyperparams, updates: jax.Array) -> jax.Array:
    """The rate of update number ``updates``: linear decay to 0 over ``lr_decay_updates``."""
    return linearly_decayed(hparams.learning_rate, updates, hparams.lr_decay_updates)


def update(
    agent: Agent,
    trajectory: Trajectory,
    hparams: Hyperparams,
    config: Config,
    updates: jax.Array | int = 0,
) -> tuple[Agent, dict[str, jax.Array]]:
    """One AdamW step on a batch of episodes at the hyperparameters' rates; the observation
    statistics then take in the batch."""
    grads, metrics = jax.grad(loss_fn, has_aux=True)(
        agent.params, trajectory, hparams, config, agent.obs_stats
    )
    grads, metrics["grad_norm"] = clip_by_global_norm(grads, hparams.max_grad_norm)
    params, opt_state = injected_step(
        _adamw,
        grads,
        agent.opt_state,
        agent.params,
        learning_rate=learning_rate(hparams, updates),
        weight_decay=hparams.weight_decay,
    )
    obs_stats = agent.obs_stats
    if obs_stats is not None:
        obs_stats = normalization.update(obs_stats, trajectory.obs, trajectory.mask)
    return Agent(params, opt_state, obs_stats), metrics


def train_iteration(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, dict[str, jax.Array]]:
    """One batch of ``num_envs`` episodes and one update on it."""
    key, rollout_key = jax.random.split(state.key)
    trajectory = rollout(state.agent.params, rollout_key, config, state.agent.obs_stats)
    agent, metrics = update(state.agent, trajectory, hparams, config, state.clock.updates)
    episode_return = jnp.sum(trajectory.reward) / config.num_envs
    state = TrainState(
        agent=agent,
        key=key,
        clock=Clock(updates=state.clock.updates + 1),
        env_steps=state.env_steps + jnp.sum(trajectory.mask).astype(jnp.int32),
        train_return=episode_return,
    )
    return state, metrics


def init(key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
    """A fresh state for one seed and one hyperparameter set."""
    obs_space = episodes.observation_space(config)
    agent_key, key = jax.random.split(key)
    params = make_network(config).init(agent_key, jnp.zeros(obs_space.shape))
    optimizer = optax.inject_hyperparams(_adamw)(hparams.learning_rate, hparams.weight_decay)
    obs_dim = obs_space.shape[0]
    obs_stats = normalization.init(obs_dim) if config.normalize_obs else None
    return TrainState(
        agent=Agent(params, optimizer.init(params), obs_stats),
        key=key,
        clock=Clock(updates=jnp.int32(0)),
        env_steps=jnp.int32(0),
        train_return=jnp.float32(jnp.nan),
    )


def train_chunk(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, ChunkMetrics]:
    """``iterations_per_chunk`` rollouts and updates, then one evaluation. Pure; jit outside."""
    state, metrics = jax.lax.scan(
        lambda s, _: train_iteration(s, config, hparams),
        state,
        None,
        length=config.iterations_per_chunk,
    )
    eval_key, key = jax.random.split(state.key)
    eval_return = episodes.evaluate(act, state.agent, config, eval_key)
    state = state.replace(key=key)
    extra = {**jax.tree.map(jnp.mean, metrics), "env_steps_taken": state.env_steps}
    return state, ChunkMetrics(
        env_steps=state.clock.updates * step_slots_per_update(config),
        updates=state.clock.updates,
        eval_return=eval_return,
        train_return=state.train_return,
        extra=extra,
    )


def step_slots_per_update(config: Config) -> int:
    """``num_envs * max_episode_steps``: the env steps of a batch whose episodes all run to the
    time limit (the unit of the shared step axis, see the module docstring)."""
    return config.num_envs * episodes.make_eval_env(config).max_episode_steps


# ---- recipes --------------------------------------------------------------------------------
# Each env's default on top of the Config and Hyperparams defaults (gymnasium's REINFORCE
# tutorial), each with the reason it was chosen. The runs that chose them:
# RESULTS.md#reinforces-recipes-how-they-were-chosen.

_CONFIGS: dict[str, dict[str, Setting]] = {
    # The tutorial's network, with 16 episodes per update and normalised returns (and a 10x
    # larger rate, below)
    "rl_jax/InvertedPendulum-v5": {"num_envs": 16, "normalize_returns": True},
    "rl_jax/InvertedDoublePendulum-v5": {
        "num_envs": 32,
        "hidden": (64, 64),
        "baseline": "value",
        "value_hidden": (64, 64),
        "normalize_returns": True,
        "normalize_obs": True,
        # A small state-free exploration std: with a larger one the noisy training episodes end
        # early, and the gradient only ever sees short episodes.
        "std_mode": "param",
        "initial_std": 0.2,
        "squash_mean": True,  # an unbounded mean could leave the action bounds and stay there
    },
    "rl_jax/CartPole-v1": {"num_envs": 16, "normalize_returns": True},  # untuned
}
_HPARAMS: dict[str, dict[str, float]] = {
    # A fast rate that reaches 1,000 early, falling to 0 over the script's 300 updates so that
    # the policy stops collapsing and recovering.
    "rl_jax/InvertedPendulum-v5": {"learning_rate": 3e-3, "lr_decay_updates": 300.0},
    "rl_jax/InvertedDoublePendulum-v5": {
        "learning_rate": 1.5e-3,  # faster than 1e-3, steadier than 3e-3
        "max_grad_norm": 0.5,
        "lr_decay_updates": 300.0,  # = the script's default budget: the final policy settles
    },
    "rl_jax/CartPole-v1": {"learning_rate": 1e-3},
}

_ABOUT = {
    "rl_jax/InvertedPendulum-v5": "gymnasium's tutorial network, 16 envs, rate 3e-3 to 0",
    "rl_jax/InvertedDoublePendulum-v5": "64x64, value baseline, 32 envs, rate 1.5e-3 to 0",
    "rl_jax/CartPole-v1": "the tutorial's network, 16 envs, rate 1e-3 (untuned)",
}
RECIPES = Recipes(
    *(
        Recipe("default", about, _CONFIGS[env_id], _HPARAMS.get(env_id, {}), envs=(env_id,))
        for env_id, about in _ABOUT.items()
    )
)


# ---- the Algorithm object -------------------------------------------------------------------
class Reinforce(RecipeBook):
    """REINFORCE as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "reinforce"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        """A fresh state for one seed and one hyperparameter set."""
        return init(key, config, hparams)

    def train_chunk(
        self, state: TrainState, config: Config, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        """``iterations_per_chunk`` rollouts and updates, then one evaluation."""
        return train_chunk(state, config, hparams)

    def env_steps_per_chunk(self, config: Config) -> int:
        """Env step slots per chunk (see the module docstring)."""
        return step_slots_per_update(config) * config.iterations_per_chunk

    def policy(self, state: TrainState, config: Config) -> Callable[[jax.Array], jax.Array]:
        """``obs -> action`` of the deterministic policy of one seed's state."""
        return lambda obs: act(state.agent, obs, config)

    def make_env(self, config: Config) -> envs.Environment:
        """The env the policy acts in, for rendering."""
        return episodes.make_eval_env(config)


reinforce = Reinforce()
default_config, default_hyperparams = reinforce.default_config, reinforce.default_hyperparams
