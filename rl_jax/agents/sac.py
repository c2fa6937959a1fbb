"""SAC, soft actor-critic with a learned temperature (Haarnoja et al. 2018, "Soft Actor-Critic
Algorithms and Applications"), on the shared off-policy loop (``rl_jax.training.offpolicy``).

A tanh-squashed Gaussian actor (``rl_jax.training.squashed_gaussian``) acts by sampling; twin
critics learn the soft value ``Q(s, a) = r + gamma E[min_i Q'_i(s', a') - alpha log pi(a'|s')]``
against Polyak-averaged target critics (``discount`` 0 only at termination), the actor
minimises ``E[alpha log pi(a|s) - min_i Q_i(s, a)]``, and ``log alpha`` takes Adam steps that
hold the policy's entropy at ``target_entropy_per_dim * |A|`` (-|A| by default). Evaluation,
``best/`` and loaded policies act with ``tanh(mean)``. The pure maths is ``sac_parts``.

One update, in the paper's order: the critics learn first (their target reads the temperature
and actor from before this update), then, every ``policy_delay``-th update, the actor against
the updated critics, then the temperature from the log-densities of the actions the actor step
drew.

Options: LayerNorm in the networks (``critic_norm``, ``actor_norm``), SimBa blocks
(``network="simba"``), observations standardised (``normalize_obs``), n-step targets
(``n_step``), a fixed temperature (``learn_temperature``), Adam's ``adam_b1`` and the
update-to-data ratio (``updates_per_iteration`` per ``num_envs`` env steps). CrossQ is a learner
of its own (``rl_jax.agents.crossq``).

Usage (one seed; ``rl_jax.training.parallel`` runs seeds x hyperparameters as one program)::

    config = sac.default_config("rl_jax/Pendulum-v1")
    hparams = sac.default_hyperparams("rl_jax/Pendulum-v1")
    state = sac.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(sac.train_chunk, static_argnums=1)(state, config, hparams)
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from jax.typing import ArrayLike

from rl_jax.agents import sac_parts
from rl_jax.agents.actor_critic import CriticBatch, every_policy_delay, gather_batch
from rl_jax.agents.common import injected_step, polyak_update
from rl_jax.envs.core.spaces import Box, Space
from rl_jax.errors import UsageError
from rl_jax.training import (
    episodes,
    networks,
    normalization,
    offpolicy,
    params,
    replay,
    squashed_gaussian,
    validation,
)
from rl_jax.training.networks import Params
from rl_jax.training.normalization import RunningStats
from rl_jax.training.offpolicy import OffPolicyConfig
from rl_jax.training.params import Scalar
from rl_jax.training.recipes import Recipe, Recipes, Setting
from rl_jax.training.replay import ReplayBuffer, Transition
from rl_jax.training.squashed_gaussian import GaussianActor

# Where CrossQ's settings went when it left SAC for a learner of its own.
_CROSSQ = "is now the crossq learner's, so this is a CrossQ run (--algo crossq)"


# ---- settings and state -------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(OffPolicyConfig):
    """Static settings of SAC (the loop's are in ``OffPolicyConfig``). Defaults: the paper's
    (Table 1: 256 x 256 ReLU networks, batch 256, one update per env step, 10^6 replay)."""

    # env steps (all envs) of uniformly random actions before learning: 10 episodes of 1,000
    # steps, as the authors' own code (softlearning's development variants) starts its runs
    learning_starts: int = 10_000
    actor_hidden: tuple[int, ...] = (256, 256)  # hidden layer widths of the actor
    critic_hidden: tuple[int, ...] = (256, 256)  # hidden layer widths of each critic
    num_critics: int = 2  # critics; the target and the actor take their min
    policy_delay: int = 1  # critic updates per actor and temperature update (the paper: 1)
    network_init: networks.Initializer = "fan_in_uniform"  # see rl_jax.training.networks
    compute_dtype: str = "float32"  # matmul dtype ("bfloat16" trades precision for speed)
    # Rewards summed before bootstrapping (windows of n_step steps of one env, cut at an
    # episode's end; the steps inside a window add no entropy bonus). 1: the paper's targets.
    n_step: int = 1
    actor_activation: networks.Activation = "relu"  # the actor's nonlinearity: relu, tanh, elu
    critic_activation: networks.Activation = "relu"  # of the critics
    # "layer": a LayerNorm between each hidden linear layer of the critics and its
    # nonlinearity (RLPD, BRO). "none": the paper's.
    critic_norm: networks.Norm = "none"
    actor_norm: networks.Norm = "none"  # the actor's: "none" or "layer"
    # Adam's first-moment decay for actor and critics (the temperature's Adam keeps 0.9)
    adam_b1: float = 0.9
    # "simba" (SimBa): observations standardised by running statistics, then a linear layer,
    # one pre-LayerNorm residual block per entry of actor_hidden / critic_hidden (all one
    # width), a LayerNorm and the output layer. "mlp": the paper's MLPs.
    network: networks.Architecture = "mlp"
    # observations standardised by running statistics for the MLPs too (SimBa always does)
    normalize_obs: bool = False
    # False: the temperature stays at initial_alpha (the first SAC paper's fixed alpha)
    learn_temperature: bool = True
    log_std_min: float = -20.0  # lower clip of the actor's log-std (softlearning's)
    log_std_max: float = 2.0  # upper clip of the actor's log-std

    # CrossQ's settings, recorded by SAC runs before CrossQ became a learner of its own: the
    # value a run recorded when it was not CrossQ (such runs load as SAC runs).
    RETIRED: ClassVar[dict[str, tuple[Any, str]]] = {
        "target_networks": (True, _CROSSQ),
        "renorm_warmup": (100_000, _CROSSQ),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.num_critics < 1 or self.policy_delay < 1 or self.n_step < 1:
            raise ValueError("num_critics, policy_delay and n_step must be >= 1")
        if self.network_init not in networks.INITS:
            raise ValueError(f"network_init must be one of {networks.INITS}")
        for name in ("actor_activation", "critic_activation"):
            if getattr(self, name) not in networks.ACTIVATIONS:
                raise ValueError(f"{name} must be one of {tuple(networks.ACTIVATIONS)}")
        for name in ("critic_norm", "actor_norm"):
            if getattr(self, name) not in ("none", "layer"):
                raise ValueError(
                    f"{name} must be 'none' or 'layer' (batch renormalisation is CrossQ's, a "
                    "learner of its own now: --algo crossq)"
                )
        hidden = {"actor_hidden": self.actor_hidden, "critic_hidden": self.critic_hidden}
        networks.check_architecture(self.network, hidden, (self.critic_norm, self.actor_norm))
        if self.log_std_min >= self.log_std_max:
            raise ValueError("log_std_min must be below log_std_max")

    @property
    def standardizes_obs(self) -> bool:
        """Whether the networks read observations standardised by running statistics."""
        return self.normalize_obs or self.network == "simba"


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: the paper's (Table 1)."""

    actor_lr: Scalar = 3e-4  # Adam step size of the actor
    critic_lr: Scalar = 3e-4  # Adam step size of the critics
    alpha_lr: Scalar = 3e-4  # Adam step size of log(alpha)
    gamma: Scalar = 0.99  # discount
    tau: Scalar = 0.005  # Polyak step of the target critics after every critic update
    initial_alpha: Scalar = 1.0  # the temperature at the start (throughout if not learned)
    # the entropy the temperature holds the policy at, per action dim (the paper: -1, i.e. -|A|)
    target_entropy_per_dim: Scalar = -1.0


@struct.dataclass
class Agent:
    """Parameters, targets, optimizer states and, where kept, observation statistics."""

    actor: Params  # actor parameters
    critics: Params  # critic parameters, leaves [num_critics, ...]
    target_critics: Params  # their Polyak copies
    log_alpha: jax.Array  # [] float32, log of the temperature
    actor_opt: optax.OptState  # optax inject_hyperparams(adam) states: they hold the rates in use
    critic_opt: optax.OptState
    alpha_opt: optax.OptState
    # simba / normalize_obs: the running statistics of the observations acted on (else None)
    obs_stats: RunningStats | None = None


# ---- networks -----------------------------------------------------------------------------------
class Networks(NamedTuple):
    """The actor, one critic module (stacked ``num_critics`` times in the parameters) and the
    bounds the actions live in."""

    actor: GaussianActor
    critic: networks.Critic
    low: np.ndarray  # [action_dim]
    high: np.ndarray


def build_networks(config: Config, action_space: Space) -> Networks:
    """Actor and critic modules for a bounded 1-D Box action space."""
    if not (
        isinstance(action_space, Box) and action_space.bounded and len(action_space.shape) == 1
    ):
        raise TypeError(f"SAC needs a bounded 1-D Box action space, got {action_space}")
    dtype, init = jnp.dtype(config.compute_dtype), config.network_init
    actor_layers = networks.Layers(
        hidden=config.actor_hidden,
        activation=config.actor_activation,
        initializer=init,
        norm=config.actor_norm,
        architecture=config.network,
        dtype=dtype,
    )
    critic_layers = networks.Layers(
        hidden=config.critic_hidden,
        activation=config.critic_activation,
        initializer=init,
        norm=config.critic_norm,
        architecture=config.network,
        dtype=dtype,
    )
    actor = GaussianActor(
        layers=actor_layers,
        action_dim=action_space.shape[0],
        log_std_min=config.log_std_min,
        log_std_max=config.log_std_max,
    )
    critic = networks.Critic(layers=critic_layers)
    return Networks(actor, critic, action_space.low.copy(), action_space.high.copy())


@functools.lru_cache(maxsize=64)
def make_networks(config: Config) -> Networks:
    """The networks for ``config.env_id`` (cached: called at every trace)."""
    return build_networks(config, episodes.action_space(config))


def actor_outputs(nets: Networks, actor: Params, obs: jax.Array):
    """``(mean, log_std)`` ``[B, A]`` each, pre-tanh."""
    return nets.actor.apply(actor, obs)


def sampled_action(nets: Networks, key: jax.Array, mean: jax.Array, log_std: jax.Array):
    """``(action in env units [B, A], log pi [B])``, reparameterised (``squashed_gaussian``)."""
    a, log_pi = squashed_gaussian.sample(key, mean, log_std)
    return squashed_gaussian.rescale(a, nets.low, nets.high), log_pi


def critic_values(nets: Networks, critics: Params, obs: jax.Array, action: jax.Array):
    """``[num_critics, B]``: every stacked critic at ``(obs, action)``."""
    return networks.apply_stacked(nets.critic, critics, obs, action)


# ---- losses on networks -------------------------------------------------------------------------
def critic_loss_fn(
    critics: Params,
    target_critics: Params,
    actor: Params,
    batch: CriticBatch,
    key: jax.Array,
    alpha: jax.Array,
    nets: Networks,
) -> tuple[jax.Array, jax.Array]:
    """``(loss, q_tm1)`` of the soft TD error; ``a' ~ pi(.|s')`` is drawn with ``key`` and
    enters as data."""
    mean, log_std = actor_outputs(nets, actor, batch.next_obs)
    a_t, log_pi_t = jax.lax.stop_gradient(sampled_action(nets, key, mean, log_std))
    q_t = critic_values(nets, target_critics, batch.next_obs, a_t)
    q_tm1 = critic_values(nets, critics, batch.obs, batch.action)
    loss = sac_parts.soft_critic_loss(q_tm1, batch.r_t, batch.discount_t, q_t, log_pi_t, alpha)
    return loss, q_tm1


def actor_loss_fn(
    actor: Params, critics: Params, obs: jax.Array, key: jax.Array, alpha: jax.Array, nets: Networks
) -> tuple[jax.Array, jax.Array]:
    """``(loss, log_pi [B])``: the soft policy loss at actions drawn with ``key``, through the
    min of every critic."""
    mean, log_std = actor_outputs(nets, actor, obs)
    action, log_pi = sampled_action(nets, key, mean, log_std)
    q = critic_values(nets, critics, obs, action)
    return sac_parts.soft_policy_loss(q, log_pi, alpha), log_pi


# ---- one update ---------------------------------------------------------------------------------
def adam(learning_rate: ArrayLike, b1: ArrayLike = 0.9) -> optax.GradientTransformation:
    """Adam whose numbers are state (``optax.inject_hyperparams``): a checkpoint records them,
    and each step reads them there."""
    return optax.inject_hyperparams(optax.adam)(learning_rate=learning_rate, b1=b1)


def adam_step(
    grads: optax.Updates, opt_state: optax.OptState, params: optax.Params, rate: ArrayLike
) -> tuple[optax.Params, optax.OptState]:
    """``(params, opt_state)`` after one Adam step at ``rate``, written into the state first;
    the state's own ``b1`` (set at init) and other numbers are the step's."""
    return injected_step(optax.adam, grads, opt_state, params, learning_rate=rate)


def sample(
    buffer: ReplayBuffer[Transition], key: jax.Array, config: Config, hparams: Hyperparams
) -> CriticBatch:
    """A uniform batch: one-step transitions, or windows of ``n_step`` steps folded."""
    rows, columns = replay.sample_indices(buffer, key, config.batch_size)
    return gather_batch(buffer, rows, columns, hparams.gamma, config.n_step)


def normalized_batch(agent: Agent, batch: CriticBatch) -> CriticBatch:
    """The batch as the networks see it (standardised with today's statistics, if kept)."""
    if agent.obs_stats is None:
        return batch
    return batch._replace(
        obs=normalization.normalize(agent.obs_stats, batch.obs),
        next_obs=normalization.normalize(agent.obs_stats, batch.next_obs),
    )


def alpha_of(agent: Agent) -> jax.Array:
    """The temperature as the losses read it: a constant for them."""
    return jax.lax.stop_gradient(jnp.exp(agent.log_alpha))


def critic_step(
    agent: Agent, batch: CriticBatch, key: jax.Array, hparams: Hyperparams, nets: Networks
) -> tuple[Agent, jax.Array, jax.Array]:
    """``(agent, loss, q_tm1)`` after one critic step and a Polyak step of the targets."""
    inputs = (agent.target_critics, agent.actor, batch, key, alpha_of(agent), nets)
    (loss, q_tm1), grads = jax.value_and_grad(critic_loss_fn, has_aux=True)(agent.critics, *inputs)
    critics, opt = adam_step(grads, agent.critic_opt, agent.critics, hparams.critic_lr)
    targets = polyak_update(agent.target_critics, critics, hparams.tau)
    return (
        dataclasses.replace(agent, critics=critics, critic_opt=opt, target_critics=targets),
        loss,
        q_tm1,
    )


def actor_and_temperature_step(
    agent: Agent,
    obs: jax.Array,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    nets: Networks,
) -> tuple[Agent, tuple[jax.Array, jax.Array, jax.Array]]:
    """``(agent, (actor loss, temperature loss, entropy estimate))`` after an actor step and,
    with ``learn_temperature``, a step of ``log_alpha`` towards the target entropy."""
    inputs = (agent.critics, obs, key, alpha_of(agent), nets)
    (loss, log_pi), grads = jax.value_and_grad(actor_loss_fn, has_aux=True)(agent.actor, *inputs)
    actor, actor_opt = adam_step(grads, agent.actor_opt, agent.actor, hparams.actor_lr)
    agent = dataclasses.replace(agent, actor=actor, actor_opt=actor_opt)
    target_entropy = hparams.target_entropy_per_dim * nets.low.shape[0]
    alpha_loss, alpha_grad = jax.value_and_grad(sac_parts.temperature_loss)(
        agent.log_alpha, log_pi, target_entropy
    )
    if config.learn_temperature:
        log_alpha, opt = adam_step(alpha_grad, agent.alpha_opt, agent.log_alpha, hparams.alpha_lr)
        agent = dataclasses.replace(agent, log_alpha=log_alpha, alpha_opt=opt)
    return agent, (loss, alpha_loss, squashed_gaussian.entropy_estimate(log_pi))


#: The keys of ``update``'s metrics.
METRICS = ("critic_loss", "actor_loss", "alpha_loss", "alpha", "entropy", "q")


def update(
    agent: Agent,
    buffer: ReplayBuffer[Transition],
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
) -> tuple[Agent, ReplayBuffer[Transition], dict[str, jax.Array]]:
    """One critic update; every ``policy_delay``-th also an actor and temperature update."""
    nets = make_networks(config)
    sample_key, critic_key, actor_key = jax.random.split(key, 3)
    batch = normalized_batch(agent, sample(buffer, sample_key, config, hparams))
    agent, critic_loss, q_tm1 = critic_step(agent, batch, critic_key, hparams, nets)

    def policy_step(agent: Agent):
        return actor_and_temperature_step(agent, batch.obs, actor_key, config, hparams, nets)

    agent, (actor_loss, alpha_loss, entropy) = every_policy_delay(
        update_index, config.policy_delay, policy_step, agent
    )
    alpha, q = jnp.exp(agent.log_alpha), jnp.mean(q_tm1)
    values = (critic_loss, actor_loss, alpha_loss, alpha, entropy, q)
    return agent, buffer, dict(zip(METRICS, values, strict=True))


# ---- acting and init ----------------------------------------------------------------------------
def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The deterministic policy, ``tanh(mean)``, in the env's own action units."""
    nets = make_networks(config)
    obs = normalization.normalize(agent.obs_stats, obs)
    mean, _ = actor_outputs(nets, agent.actor, obs)
    return squashed_gaussian.rescale(jnp.tanh(mean), nets.low, nets.high)


def explore(
    agent: Agent,
    obs: jax.Array,
    noise: jax.Array,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    clock: offpolicy.Clock | None = None,
) -> tuple[jax.Array, jax.Array]:
    """``(actions, noise)``: a sample of the policy (SAC explores through its own entropy;
    the loop's noise state is passed on unused)."""
    nets = make_networks(config)
    obs = normalization.normalize(agent.obs_stats, obs)
    mean, log_std = actor_outputs(nets, agent.actor, obs)
    return sampled_action(nets, key, mean, log_std)[0], noise


def init_agent(
    key: jax.Array, config: Config, hparams: Hyperparams, obs_space: Space, action_space: Space
) -> Agent:
    """A fresh agent: targets copies of the critics, the temperature at ``initial_alpha``."""
    nets = make_networks(config)
    actor_key, critic_key = jax.random.split(key)
    obs = jnp.zeros(obs_space.shape, jnp.float32)
    action = jnp.zeros(action_space.shape, jnp.float32)
    actor = dict(nets.actor.init(actor_key, obs))
    critics = dict(networks.init_stacked(nets.critic, critic_key, config.num_critics, obs, action))
    log_alpha = jnp.log(jnp.asarray(hparams.initial_alpha, jnp.float32))
    return Agent(
        actor=actor,
        critics=critics,
        target_critics=critics,
        log_alpha=log_alpha,
        actor_opt=adam(hparams.actor_lr, config.adam_b1).init(actor),
        critic_opt=adam(hparams.critic_lr, config.adam_b1).init(critics),
        alpha_opt=adam(hparams.alpha_lr).init(log_alpha),
        obs_stats=normalization.init(obs.shape[-1]) if config.standardizes_obs else None,
    )


def observe(
    agent: Agent,
    transitions: Transition,
    episode_return: jax.Array,
    done: jax.Array,
    clock: offpolicy.Clock,
    config: Config,
    hparams: Hyperparams,
) -> Agent:
    """Every env step: the running observation statistics (SimBa, normalize_obs) take in the
    observations acted on."""
    if agent.obs_stats is None:
        return agent
    mask = jnp.ones(transitions.obs.shape[:1], jnp.float32)
    return dataclasses.replace(
        agent, obs_stats=normalization.update(agent.obs_stats, transitions.obs, mask)
    )


LEARNER = offpolicy.Learner(init_agent, explore, act, update, METRICS, observe=observe)


# ---- recipes ------------------------------------------------------------------------------------
# Why each recipe is what it is: docs/learners/sac.md, "How the recipes were chosen".
PENDULUM, ANT, HUMANOID = "rl_jax/Pendulum-v1", "rl_jax/Ant-v5", "rl_jax/Humanoid-v5"
_CPU_ENVS = "InvertedPendulum InvertedDoublePendulum HalfCheetah Hopper Walker2d Reacher Swimmer"
RATE_1E3: dict[str, Setting] = {"actor_lr": 1e-3, "critic_lr": 1e-3, "alpha_lr": 1e-3}
PENDULUM_CONFIG: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 250,
    "learning_starts": 1_000,
    "actor_hidden": (64, 64),
    "critic_hidden": (64, 64),
}
# TD3's half-cheetah CPU loop and networks; the policy delay of 2 won on all four MuJoCo rows
# (RESULTS.md, "SAC: the policy delay of 2 on all four rows").
MUJOCO_CONFIG: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 1_250,
    "batch_size": 128,
    "learning_starts": 10_000,
    "actor_hidden": (128, 128),
    "critic_hidden": (128, 128),
    "policy_delay": 2,
}
# Adam's b1 0.5 raised Ant's return only (RESULTS.md, "SAC with Adam b1 0.5 on all four rows").
ANT_CONFIG: dict[str, Setting] = {**MUJOCO_CONFIG, "adam_b1": 0.5}
# Humanoid's raw contact forces (up to ~1,900) saturate an actor that reads them raw.
HUMANOID_CONFIG: dict[str, Setting] = {**MUJOCO_CONFIG, "normalize_obs": True}
# The paper's Table 1, in one env, with its code's 10,000 random steps first.
SAC_PAPER_CONFIG: dict[str, Setting] = {
    "num_envs": 1,
    "updates_per_iteration": 1,
    "iterations_per_chunk": 5_000,
    "batch_size": 256,
    "buffer_size": 1_000_000,
    "learning_starts": 10_000,
    "actor_hidden": (256, 256),
    "critic_hidden": (256, 256),
}
SAC_PAPER_HPARAMS: dict[str, Setting] = {
    "actor_lr": 3e-4,
    "critic_lr": 3e-4,
    "alpha_lr": 3e-4,
    "tau": 0.005,
    "gamma": 0.99,
    "target_entropy_per_dim": -1.0,
}
RECIPES = Recipes(
    Recipe(
        "default",
        "64x64 networks at rate 1e-3, 4 envs x 4 updates per iteration, 1,000 warm-up steps",
        PENDULUM_CONFIG,
        RATE_1E3,
        envs=(PENDULUM,),
    ),
    Recipe(
        "default",
        "CPU: 128x128 at rate 1e-3 in TD3's CPU loop (batch 128, 4 envs x 4 updates, 10,000 "
        "warm-up steps), actor and temperature every 2nd update",
        MUJOCO_CONFIG,
        RATE_1E3,
        envs=tuple(f"rl_jax/{name}-v5" for name in _CPU_ENVS.split()),
    ),
    Recipe(
        "default",
        "the MuJoCo CPU recipe with Adam b1 0.5 for actor and critics",
        ANT_CONFIG,
        RATE_1E3,
        envs=(ANT,),
    ),
    Recipe(
        "default",
        "the MuJoCo CPU recipe, observations standardised by running statistics",
        HUMANOID_CONFIG,
        RATE_1E3,
        envs=(HUMANOID,),
    ),
    Recipe(
        "sac-paper",
        "the SAC paper's: 256x256 at rate 3e-4, one env, one update per step, batch 256, "
        "10,000 warm-up steps",
        SAC_PAPER_CONFIG,
        SAC_PAPER_HPARAMS,
    ),
)
# SAC's recipes that were CrossQ's, and what to type for them now.
MOVED_RECIPES = {
    "crossq": "--algo crossq (its published settings)",
    "crossq-cpu": "--algo crossq --recipe cpu (CrossQ at CPU sizes)",
}


# ---- the Algorithm object -----------------------------------------------------------------------
class SAC(offpolicy.OffPolicyAlgorithm[Config]):
    """SAC as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "sac"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    learner = LEARNER
    ranges = {
        "adam_b1": validation.Range(0.0, 1.0, high_open=True),
        "initial_alpha": validation.POSITIVE,
    }

    def recipe(self, env_id: str, name: str | None = None) -> Recipe:
        """Recipe ``name`` for ``env_id``; a ``UsageError`` saying what to type for a recipe
        that moved to the crossq learner."""
        if name in MOVED_RECIPES:
            raise UsageError(
                f"--recipe {name}: CrossQ is a learner of its own now (on TD3's actor): "
                + MOVED_RECIPES[name]
            )
        return super().recipe(env_id, name)


sac = SAC()
