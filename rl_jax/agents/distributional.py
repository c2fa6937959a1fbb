"""Distributional DQN: C51 (Bellemare et al. 2017, ``--algo c51``) and QR-DQN (Dabney et al.
2018, ``--algo qrdqn``), one learner with two heads on DQN's machinery.

The Q-network gives, per action, a distribution of returns in place of its mean: with
``head="categorical"`` (C51) the logits of ``num_atoms`` probabilities on a fixed support from
``v_min`` to ``v_max``; with ``head="quantile"`` (QR-DQN) ``num_atoms`` return values at the
quantile levels ``(2i + 1) / 2N``. A distribution's mean is its Q-value: acting (epsilon-greedy),
the greedy policy and the bootstrap action (the target net's greedy action, or with ``double``
the online net's, valued by the target net) all read it, over the legal actions alone for an env
with an action mask. The n-step target distribution ``G + D z`` of the bootstrap action is
projected onto the support and fitted by cross-entropy (C51), or its samples fitted by the
quantile Huber loss with ``kappa = huber_delta`` (QR-DQN); the maths is ``distributional_parts``.
With ``prioritized`` replay a sample's priority is its own loss.

Everything else is DQN's (``rl_jax.agents.dqn``): the settings this ``Config`` extends (n-step,
Double, prioritized replay, LayerNorm, policy checkpoints, the conv torsos of ``PixelConfig`` and
``ImageConfig``), the replay, the schedules, the agent and the loop. Why a learner of its own and
not DQN options: the head changes the network's output, the loss, acting and bootstrapping, so
every DQN function would branch on it (docs/learners/distributional.md).

Usage is DQN's::

    config = distributional.c51.default_config("rl_jax/CartPole-v1")
    hparams = distributional.c51.default_hyperparams("rl_jax/CartPole-v1")
    state = distributional.c51.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(distributional.c51.train_chunk, static_argnums=1)(
        state, config, hparams
    )
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, cast

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.typing import ArrayLike

from rl_jax import envs
from rl_jax.agents import distributional_parts as parts
from rl_jax.agents import dqn
from rl_jax.agents.common import clipped_adam, injected_step, polyak_update
from rl_jax.agents.dqn import Agent
from rl_jax.agents.dqn_parts import Buffer
from rl_jax.agents.q_learning import masked_argmax, masked_epsilon_greedy
from rl_jax.training import episodes, networks, offpolicy, policy_checkpoints, validation
from rl_jax.training.offpolicy import Clock, TrainState
from rl_jax.training.recipes import Recipe, Recipes, Setting
from rl_jax.training.replay import NStepBatch

HEADS = ("categorical", "quantile")


# ---- settings -------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(dqn.Config):
    """DQN's settings and the distribution's."""

    head: str = "categorical"  # "categorical" (C51) or "quantile" (QR-DQN)
    num_atoms: int = 51  # C51: atoms of the support (the paper's 51); QR-DQN: quantiles
    v_min: float = -10.0  # C51: the support's lowest return (the paper's Atari -10)
    v_max: float = 10.0  # C51: the support's highest return

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.head not in HEADS:
            raise ValueError(f"head must be one of {HEADS}, got {self.head!r}")
        if self.num_atoms < 2:
            raise ValueError(f"num_atoms must be >= 2, got {self.num_atoms}")
        if self.v_min >= self.v_max:
            raise ValueError(f"v_min ({self.v_min}) must be below v_max ({self.v_max})")
        if self.dueling:
            raise ValueError("dueling is not available with a distributional head")


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImageConfig(Config, dqn.ImageConfig):
    """On image observations (``dqn.IMAGE_ENVS``, MinAtar): DQN's ``ImageConfig`` torso."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class PixelConfig(Config, dqn.PixelConfig):
    """On stacked frames (``dqn.PIXEL_ENVS``): DQN's ``PixelConfig`` torso and frame replay."""


@struct.dataclass
class Hyperparams(dqn.Hyperparams):
    """DQN's hyperparameters (``huber_delta`` is QR-DQN's kappa) and Adam's epsilon."""

    # Adam's epsilon: both papers' 0.01 / 32 (optax's 1e-8 is DQN's)
    adam_eps: ArrayLike = 0.01 / 32


# ---- the network ----------------------------------------------------------------------------
@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> networks.QNetwork:
    """DQN's Q-network with ``num_actions * num_atoms`` outputs (cached: called at every trace);
    ``distributions`` shapes them ``[..., A, N]``."""
    space = episodes.action_space(config)
    if not isinstance(space, envs.Discrete):
        raise TypeError(f"distributional DQN needs a discrete action space, got {space}")
    layers = networks.Layers(
        hidden=config.hidden, initializer=config.network_init, norm=config.norm
    )
    outputs = space.n * config.num_atoms
    return networks.QNetwork(layers=layers, num_actions=outputs, **dqn.conv_settings(config))


def num_actions(config: Config) -> int:
    """The env's number of actions."""
    return make_network(config).num_actions // config.num_atoms


def distributions(params: optax.Params, obs: jax.Array, config: Config) -> jax.Array:
    """Per action, the logits (C51) or quantiles (QR-DQN): ``[..., A, N]``."""
    out = cast(jax.Array, make_network(config).apply(params, obs))
    return out.reshape(*out.shape[:-1], num_actions(config), config.num_atoms)


def support(config: Config) -> jax.Array:
    """C51's atoms ``[N]``."""
    return parts.categorical_support(config.v_min, config.v_max, config.num_atoms)


def mean_values(values: jax.Array, config: Config) -> jax.Array:
    """The Q-values ``[..., A]``, each distribution's mean, of ``distributions``' output."""
    if config.head == "categorical":
        return parts.categorical_q_values(values, support(config))
    return parts.quantile_q_values(values)


def q_values(params: optax.Params, obs: jax.Array, config: Config) -> jax.Array:
    """The Q-values ``[..., A]`` of the network ``params``."""
    return mean_values(distributions(params, obs, config), config)


# ---- the loss and one update ----------------------------------------------------------------
def bootstrap_actions(
    values_t: jax.Array, online_t: jax.Array | None, legal_t: jax.Array | None, config: Config
) -> jax.Array:
    """The greedy (legal) action of the target net's means, or with ``double`` of the online
    net's (``online_t``, its distributions at the next obs): ``[B]``."""
    selector = mean_values(values_t if online_t is None else online_t, config)
    if legal_t is not None:
        return masked_argmax(selector, legal_t)
    return jnp.argmax(selector, axis=-1).astype(jnp.int32)


def loss_fn(
    online: optax.Params,
    target: optax.Params,
    batch: NStepBatch,
    weights: jax.Array,
    hparams: Hyperparams,
    config: Config,
) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """``(loss, (per-sample loss [B], mean Q of the taken actions))``; the target net enters
    only through the stopped-gradient target."""
    values_tm1 = distributions(online, batch.obs, config)
    values_t = jax.lax.stop_gradient(distributions(target, batch.next_obs, config))
    online_t = distributions(online, batch.next_obs, config) if config.double else None
    a_t = bootstrap_actions(values_t, online_t, batch.next_legal, config)
    total, discount = parts.n_step_return(batch.r_t, batch.discount_t)
    bootstrap = parts.select_action(values_t, a_t)  # [B, N]
    if config.head == "categorical":
        target_probs = parts.categorical_projection(
            support(config), jax.nn.softmax(bootstrap, axis=-1), total, discount
        )
        loss, per_sample = parts.categorical_loss(values_tm1, batch.action, target_probs, weights)
    else:
        samples = total[:, None] + discount[:, None] * bootstrap
        loss, per_sample = parts.quantile_huber_loss(
            values_tm1, batch.action, samples, weights, hparams.huber_delta
        )
    q_tm1 = mean_values(values_tm1, config)
    q_taken = jnp.take_along_axis(q_tm1, batch.action[:, None].astype(jnp.int32), axis=-1)
    return loss, (per_sample, jnp.mean(q_taken))


def update(
    agent: Agent,
    buffer: Buffer,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
) -> tuple[Agent, Buffer, dict[str, jax.Array]]:
    """One gradient update (on DrQ-shifted frames with a ``PixelConfig``'s ``augment_shift``),
    then (when due) a target step and new priorities (each sample's loss)."""
    replay = dqn.replay_for(config)
    batch, weights, indices = replay.sample(buffer, key, hparams, update_index)
    if isinstance(config, PixelConfig) and config.augment_shift:
        batch = dqn.shifted_batch(batch, key, config.augment_shift)
    (loss, (per_sample, q)), grads = jax.value_and_grad(loss_fn, has_aux=True)(
        agent.online, agent.target, batch, weights, hparams, config
    )
    env_steps = offpolicy.env_steps_at_update(update_index, config)
    online, opt_state = injected_step(
        clipped_adam,
        grads,
        agent.opt_state,
        agent.online,
        learning_rate=dqn.learning_rate_at(env_steps, hparams),
        max_grad_norm=hparams.max_grad_norm,
        adam_eps=hparams.adam_eps,
    )
    due = (update_index + 1) % config.target_update_period == 0
    target = jax.lax.cond(
        due, lambda: polyak_update(agent.target, online, hparams.tau), lambda: agent.target
    )
    agent = dataclasses.replace(agent, online=online, target=target, opt_state=opt_state)
    buffer = replay.write_priorities(buffer, indices, per_sample, hparams)
    return agent, buffer, {"loss": loss, "q": q, "epsilon": dqn.epsilon_at(env_steps, hparams)}


# ---- acting ---------------------------------------------------------------------------------
def greedy(
    params: optax.Params, obs: jax.Array, config: Config, legal: jax.Array | None = None
) -> jax.Array:
    """Greedy actions ``[N]`` int32 of the means of ``params``' distributions (among the
    ``legal`` ones, bool ``[N, A]``, for an env with an action mask)."""
    q = q_values(params, obs, config)
    if legal is not None:
        return masked_argmax(q, legal)
    return jnp.argmax(q, axis=-1).astype(jnp.int32)


def act(agent: Agent, obs: jax.Array, config: Config, legal: jax.Array | None = None) -> jax.Array:
    """Greedy actions of the online network, or of the checkpoint's (``dqn.policy_params``)."""
    return greedy(dqn.policy_params(agent, config), obs, config, legal)


def explore(
    agent: Agent,
    obs: jax.Array,
    noise: jax.Array,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    clock: Clock,
    legal: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """``(actions, noise)``: epsilon-greedy on the means, as DQN's ``explore`` (among the
    ``legal`` actions for an env with an action mask); ``noise`` is passed through."""
    checkpoint = agent.checkpoint if config.policy_checkpoints else None
    acting = agent.online if checkpoint is None else checkpoint.assessed
    q = q_values(acting, obs, config)
    everything = jnp.ones(q.shape, jnp.bool_)
    epsilon = dqn.epsilon_at(clock.env_steps, hparams)
    return masked_epsilon_greedy(key, q, everything if legal is None else legal, epsilon), noise


# ---- init and the loop's learner ------------------------------------------------------------
def init_agent(
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    obs_space: envs.Space,
    action_space: envs.Space,
) -> Agent:
    """A fresh agent: the target network a copy of the online one (and a checkpoint of it with
    ``policy_checkpoints``)."""
    online = make_network(config).init(key, jnp.zeros(obs_space.shape, jnp.float32))
    optimizer = optax.inject_hyperparams(clipped_adam)(
        hparams.learning_rate, hparams.max_grad_norm, hparams.adam_eps
    )
    agent = Agent(online=online, target=online, opt_state=optimizer.init(online))
    if config.policy_checkpoints:
        checkpoint = policy_checkpoints.init(online, config.num_envs, config.learning_starts)
        agent = dataclasses.replace(agent, checkpoint=checkpoint)
    return agent


LEARNER = offpolicy.Learner(
    init_agent,
    explore,
    act,
    update,
    ("loss", "q", "epsilon"),
    dqn.init_buffer,
    dqn.add_to_buffer,
    dqn.observe,
)


# ---- recipes --------------------------------------------------------------------------------
# CartPole: DQN's recipe (its loop, 3-step returns and TD7's policy checkpoints) with a slower
# rate, Adam's default epsilon (as CleanRL's classic-control C51) and the distribution of each
# learner. C51's support is CleanRL's c51.py for classic control: 101 atoms on [-100, 100];
# CartPole's discounted returns lie in [0, 100]. QR-DQN: sb3-contrib's default of 50 quantiles,
# kappa 1 (the paper's 200 pairs every quantile with every target sample: 16 times the loss's
# work, and no better here; RESULTS.md).
_DQN_CARTPOLE = dqn.dqn.recipe("rl_jax/CartPole-v1")
_CARTPOLE_HPARAMS: dict[str, Setting] = {
    **_DQN_CARTPOLE.hparams,
    "learning_rate": 1e-3,
    "adam_eps": 1e-8,
}
C51_CARTPOLE: dict[str, Setting] = {
    **_DQN_CARTPOLE.config,
    "head": "categorical",
    "num_atoms": 101,
    "v_min": -100.0,
    "v_max": 100.0,
}
QR_CARTPOLE: dict[str, Setting] = {**_DQN_CARTPOLE.config, "head": "quantile", "num_atoms": 50}

# MinAtar: DQN's MinAtar recipe (the MinAtar paper's DQN) with each paper's distribution and
# Adam epsilon 0.01/32. C51: 51 atoms on [-10, 10] (the C51 paper's Atari support; Dopamine's
# c51.gin). QR-DQN: 200 quantiles, kappa 1 (the QR-DQN paper; Dopamine's quantile.gin).
C51_MINATAR: dict[str, Setting] = {
    **dqn.MINATAR_CONFIG,
    "head": "categorical",
    "num_atoms": 51,
    "v_min": -10.0,
    "v_max": 10.0,
}
QR_MINATAR: dict[str, Setting] = {**dqn.MINATAR_CONFIG, "head": "quantile", "num_atoms": 200}
_MINATAR_HPARAMS: dict[str, Setting] = {**dqn.MINATAR_HPARAMS, "adam_eps": 0.01 / 32}

C51_RECIPES = Recipes(
    Recipe(
        "default",
        "DQN's CartPole recipe, rate 1e-3, 101 atoms on [-100, 100] (CleanRL's)",
        C51_CARTPOLE,
        _CARTPOLE_HPARAMS,
        envs=("rl_jax/CartPole-v1",),
        total_steps=100_000,
    ),
    Recipe(
        "default",
        "DQN's MinAtar recipe (the MinAtar paper's), 51 atoms on [-10, 10] (the C51 paper's)",
        C51_MINATAR,
        _MINATAR_HPARAMS,
        envs=dqn.IMAGE_ENVS,
        total_steps=5_000_000,
    ),
)
QR_RECIPES = Recipes(
    Recipe(
        "default",
        "DQN's CartPole recipe, rate 1e-3, 50 quantiles (sb3-contrib's), kappa 1",
        QR_CARTPOLE,
        _CARTPOLE_HPARAMS,
        envs=("rl_jax/CartPole-v1",),
        total_steps=100_000,
    ),
    Recipe(
        "default",
        "DQN's MinAtar recipe (the MinAtar paper's), 200 quantiles, kappa 1",
        QR_MINATAR,
        _MINATAR_HPARAMS,
        envs=dqn.IMAGE_ENVS,
        total_steps=5_000_000,
    ),
)


# ---- the Algorithm objects ------------------------------------------------------------------
class DistributionalDQN(offpolicy.OffPolicyAlgorithm[Config]):
    """C51 or QR-DQN (by ``head``) as an ``rl_jax.training.algorithm.Algorithm``."""

    config_type, hparams_type = Config, Hyperparams
    learner = LEARNER
    ranges = {**dqn.DQN.ranges, "adam_eps": validation.POSITIVE}

    def __init__(self, name: str, head: str, recipes: Recipes) -> None:
        self.name, self.head, self.recipes = name, head, recipes

    def default_config(self, env_id: str, recipe: str | None = None, **overrides: Any) -> Config:
        """The recipe's ``Config`` with this learner's ``head``: an ``ImageConfig`` for
        ``dqn.IMAGE_ENVS``, a ``PixelConfig`` for ``dqn.PIXEL_ENVS``."""
        values = {"head": self.head, **self.recipe(env_id, recipe).config, **overrides}
        if env_id in dqn.IMAGE_ENVS:
            return ImageConfig(env_id=env_id, **values)
        if env_id in dqn.PIXEL_ENVS:
            return PixelConfig(env_id=env_id, **values)
        return Config(env_id=env_id, **values)

    def policy(self, state: TrainState, config: Config) -> Callable[..., jax.Array]:
        """``obs -> action index`` of the greedy policy on the means (with
        ``policy_checkpoints``, the checkpoint's); for an env with an action mask
        ``(obs, legal) -> action index``, the best legal action."""
        params = dqn.policy_params(state.agent, config)
        return lambda obs, legal=None: greedy(params, obs, config, legal)

    def make_env(self, config: Config) -> envs.Environment:
        """The env the policy acts in, for rendering."""
        return episodes.make_eval_env(config)

    def loop_seeds(self, config: Config) -> bool:
        """Seeds as an unrolled loop where a ``PixelConfig`` asks for it (as DQN's)."""
        return isinstance(config, PixelConfig) and config.loop_seeds


c51 = DistributionalDQN("c51", "categorical", C51_RECIPES)
qrdqn = DistributionalDQN("qrdqn", "quantile", QR_RECIPES)
