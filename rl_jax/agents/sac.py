"""SAC, soft actor-critic with a learned temperature (Haarnoja et al. 2018, "Soft Actor-Critic
Algorithms and Applications"), on the shared off-policy loop (``rl_jax.training.offpolicy``).

A tanh-squashed Gaussian actor (``rl_jax.training.squashed_gaussian``) acts by sampling; twin
critics learn the soft value ``Q(s, a) = r + gamma E[min_i Q'_i(s', a') - alpha log pi(a'|s')]``
against Polyak-averaged target critics (``discount`` 0 only at termination), the actor
minimises ``E[alpha log pi(a|s) - min_i Q_i(s, a)]``, and ``log alpha`` takes Adam steps that
hold the policy's entropy at ``target_entropy_per_dim * |A|`` (-|A| by default). Evaluation,
``best/`` and loaded policies act with ``tanh(mean)``. The losses are in ``sac_losses``, one
update in ``sac_update``, the recipes in ``sac_recipes``.

Options: LayerNorm critics (``critic_norm="layer"``), SimBa blocks (``network="simba"``),
n-step targets (``n_step``), the update-to-data ratio (``updates_per_iteration`` per
``num_envs`` env steps), and CrossQ (Bhatt et al. 2024: ``critic_norm="batch_renorm"``,
``target_networks=False``, recipe ``crossq``).

Usage (one seed; ``rl_jax.training.parallel`` runs seeds x hyperparameters as one program)::

    config = sac.default_config("rl_jax/Pendulum-v1")
    hparams = sac.default_hyperparams("rl_jax/Pendulum-v1")
    state = sac.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(sac.train_chunk, static_argnums=1)(state, config, hparams)
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax.agents.sac_networks import (
    actor_outputs,
    deterministic_action,
    make_networks,
    sampled_action,
)
from rl_jax.agents.sac_recipes import RECIPES
from rl_jax.agents.sac_update import metric_names, update
from rl_jax.training import networks, normalization, offpolicy, params, validation
from rl_jax.training.algorithm import RecipeBook
from rl_jax.training.offpolicy import OffPolicyConfig, TrainState
from rl_jax.training.replay import Transition


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
    # critic updates per actor and temperature update (CrossQ: 3; the paper: 1)
    policy_delay: int = 1
    network_init: str = "fan_in_uniform"  # see rl_jax.training.networks
    compute_dtype: str = "float32"  # matmul dtype ("bfloat16" trades precision for speed)
    # Rewards summed before bootstrapping (windows of n_step steps of one env, cut at an
    # episode's end; the steps inside a window add no entropy bonus). 1: the paper's targets.
    n_step: int = 1
    actor_activation: str = "relu"  # hidden nonlinearity of the actor: relu, tanh or elu
    critic_activation: str = "relu"  # of the critics
    # "layer": a LayerNorm between each hidden linear layer of the critics and its
    # nonlinearity (RLPD, BRO). "batch_renorm" (CrossQ): batch renormalisation on the critics'
    # input and after each hidden nonlinearity, training mode in the critic update, evaluation
    # mode (running statistics) for the actor's loss and the targets. "none": the paper's.
    critic_norm: str = "none"
    # the actor's: "none", "layer" or "batch_renorm" (CrossQ's code: training mode in the
    # actor update, running statistics when acting and for the bootstrap actions)
    actor_norm: str = "none"
    # batch_renorm: updates of plain batch norm (no r/d corrections) while the running
    # statistics settle (CrossQ's implementation: 100,000)
    renorm_warmup: int = 100_000
    # False (CrossQ): no target critics: the online critics see the batch's (s, a) and (s', a')
    # in one forward pass, so that batch renormalisation's statistics cover both
    target_networks: bool = True
    # Adam's first-moment decay for actor and critics (CrossQ: 0.5; the temperature keeps 0.9)
    adam_b1: float = 0.9
    # "simba" (SimBa): observations standardised by running statistics, then a linear layer,
    # one pre-LayerNorm residual block per entry of actor_hidden / critic_hidden (all one
    # width), a LayerNorm and the output layer. "mlp": the paper's MLPs.
    network: str = "mlp"
    # observations standardised by running statistics for the MLPs too (SimBa always does)
    normalize_obs: bool = False
    # False: the temperature stays at initial_alpha (the first SAC paper's fixed alpha)
    learn_temperature: bool = True
    log_std_min: float = -20.0  # lower clip of the actor's log-std (softlearning's, CrossQ's)
    log_std_max: float = 2.0  # upper clip of the actor's log-std

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
            if getattr(self, name) not in networks.NORMS:
                raise ValueError(f"{name} must be one of {networks.NORMS}")
        if self.network not in networks.ARCHITECTURES:
            raise ValueError(f"network must be one of {networks.ARCHITECTURES}")
        if self.network == "simba":
            for name in ("actor_hidden", "critic_hidden"):
                widths = getattr(self, name)
                if not widths or len(set(widths)) != 1:
                    raise ValueError(f"network='simba' needs {name} of one width (w, w, ...)")
            if self.critic_norm != "none" or self.actor_norm != "none":
                raise ValueError("network='simba' has its own LayerNorms: leave the norms 'none'")
        if self.log_std_min >= self.log_std_max:
            raise ValueError("log_std_min must be below log_std_max")

    @property
    def standardizes_obs(self) -> bool:
        """Whether the networks read observations standardised by running statistics."""
        return self.normalize_obs or self.network == "simba"


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: the paper's (Table 1)."""

    actor_lr: Any = 3e-4  # Adam step size of the actor
    critic_lr: Any = 3e-4  # Adam step size of the critics
    alpha_lr: Any = 3e-4  # Adam step size of log(alpha)
    gamma: Any = 0.99  # discount
    tau: Any = 0.005  # Polyak step of the target critics after every critic update
    initial_alpha: Any = 1.0  # the temperature at the start (throughout if not learned)
    # the entropy the temperature holds the policy at, per action dim (the paper: -1, i.e. -|A|)
    target_entropy_per_dim: Any = -1.0


@struct.dataclass
class Agent:
    """Parameters, targets and optimizer states; None where an option is off."""

    actor: Any  # actor parameters
    critics: Any  # critic parameters, leaves [num_critics, ...]
    target_critics: Any  # Polyak copies (None without target networks)
    log_alpha: jax.Array  # [] float32, log of the temperature
    actor_opt: Any  # optax inject_hyperparams(adam) states: they hold the rates in use
    critic_opt: Any
    alpha_opt: Any
    actor_stats: Any = None  # actor_norm "batch_renorm": the actor's running statistics
    critic_stats: Any = None  # critic_norm "batch_renorm": the critics' [num_critics, ...]
    obs_stats: Any = None  # simba / normalize_obs: RunningStats of the observations acted on


# ---- acting and init ----------------------------------------------------------------------------
def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The deterministic policy, ``tanh(mean)``, in the env's own action units."""
    obs = normalization.normalize(agent.obs_stats, obs)
    return deterministic_action(make_networks(config), agent.actor, agent.actor_stats, obs)


def explore(agent: Agent, obs, noise, key, config: Config, hparams: Hyperparams, clock=None):
    """``(actions, noise)``: a sample of the policy (SAC explores through its own entropy;
    the loop's noise state is passed on unused)."""
    nets = make_networks(config)
    obs = normalization.normalize(agent.obs_stats, obs)
    mean, log_std = actor_outputs(nets, agent.actor, agent.actor_stats, obs)
    return sampled_action(nets, key, mean, log_std)[0], noise


def _adam(learning_rate, b1: float = 0.9) -> optax.GradientTransformation:
    return optax.inject_hyperparams(optax.adam)(learning_rate=learning_rate, b1=b1)


def init_agent(key, config: Config, hparams: Hyperparams, obs_space, action_space) -> Agent:
    nets = make_networks(config)
    actor_key, critic_key = jax.random.split(key)
    obs = jnp.zeros(obs_space.shape, jnp.float32)
    action = jnp.zeros(action_space.shape, jnp.float32)
    # Batch renormalisation's statistics are state, not parameters: the optimizers never see them.
    actor = dict(nets.actor.init(actor_key, obs))
    actor_stats = actor.pop("batch_stats", None)
    critics = dict(networks.init_stacked(nets.critic, critic_key, config.num_critics, obs, action))
    critic_stats = critics.pop("batch_stats", None)
    log_alpha = jnp.log(jnp.asarray(hparams.initial_alpha, jnp.float32))
    b1 = config.adam_b1
    return Agent(
        actor=actor,
        critics=critics,
        target_critics=critics if config.target_networks else None,
        log_alpha=log_alpha,
        actor_opt=_adam(hparams.actor_lr, b1).init(actor),
        critic_opt=_adam(hparams.critic_lr, b1).init(critics),
        alpha_opt=_adam(hparams.alpha_lr).init(log_alpha),
        actor_stats=actor_stats,
        critic_stats=critic_stats,
        obs_stats=normalization.init(obs.shape[-1]) if config.standardizes_obs else None,
    )


def observe(agent: Agent, transitions: Transition, episode_return, done, clock, config, hparams):
    """Every env step: the running observation statistics (SimBa, normalize_obs) take in the
    observations acted on."""
    if not config.standardizes_obs:
        return agent
    mask = jnp.ones(transitions.obs.shape[:1], jnp.float32)
    return agent.replace(obs_stats=normalization.update(agent.obs_stats, transitions.obs, mask))


LEARNER = offpolicy.Learner(init_agent, explore, act, update, metric_names, observe=observe)


# ---- the Algorithm object -------------------------------------------------------------------
class SAC(RecipeBook):
    """SAC as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "sac"
    config_type = Config
    hparams_type = Hyperparams
    recipes = RECIPES
    ranges = {
        "renorm_warmup": validation.NON_NEGATIVE,
        "adam_b1": validation.Range(0.0, 1.0, high_open=True),
        "initial_alpha": validation.POSITIVE,
    }

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        return offpolicy.init(LEARNER, key, config, hparams)

    def train_chunk(self, state: TrainState, config: Config, hparams: Hyperparams):
        return offpolicy.train_chunk(LEARNER, state, config, hparams)

    def policy(self, state: TrainState, config: Config):
        """``obs -> action`` (env units) of the deterministic policy of one seed's state."""
        agent = state.agent
        return lambda obs: act(agent, obs, config)


sac = SAC()
