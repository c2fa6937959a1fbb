"""TD3 (Fujimoto et al. 2018) and DDPG (that paper's "our DDPG" baseline) from one code path.

What tells them apart is settings only: TD3 uses ``num_critics=2`` (clipped double Q: the target
takes the min of twin target critics), ``policy_delay=2`` (actor and target networks update after
every second critic update) and ``target_noise=0.2`` clipped at ``0.5`` (target policy smoothing);
DDPG is ``num_critics=1``, ``policy_delay=1``, ``target_noise=0``. Noise scales are fractions of
the action half-range ``(high - low) / 2``, as the reference code scales them by ``max_action``.

Usage (one seed; ``rl_jax.training.parallel`` runs seeds x hyperparameters as one program)::

    config = td3.default_config("rl_jax/Pendulum-v1")          # static, frozen
    hparams = td3.default_hyperparams()                         # arrays, vmappable
    state = td3.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(td3.train_chunk, static_argnums=1)
    state, metrics = chunk(state, config, hparams)              # metrics.eval_return, ...
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax.agents.td3_agent import (  # noqa: F401  (re-exported)
    Agent,
    AgentWithOptions,
    Encoders,
    Policy,
    PolicyCheckpoint,
    ValueRange,
    act_with,
    current_policy,
    fixed_encoders,
    hard_target_update,
    init_checkpoint,
    normalized,
    normalized_batch,
    observe,
)
from rl_jax.agents.td3_losses import (  # noqa: F401  (re-exported: the tests read them here)
    CriticAux,
    CriticBatch,
    actor_loss_fn,
    clipped_double_q_target,
    critic_loss,
    critic_loss_fn,
    deterministic_policy_loss,
    encoder_loss_fn,
    smoothed_target_action,
    target_action,
)
from rl_jax.agents.td3_networks import (  # noqa: F401  (build_networks re-exported)
    Networks,
    build_networks,
    make_networks,
    policy_action,
    row,
)
from rl_jax.agents.td3_recipes import (  # noqa: F401  (re-exported: scripts read them here)
    FAST_CHEETAH_CONFIG,
    FAST_CHEETAH_HPARAMS,
    GPU_CHEETAH_CONFIG,
    HPARAM_RECIPES,
    MUJOCO_SUITE,
    PAPER_2018_CONFIG,
    PAPER_2018_HPARAMS,
    PAPER_CONFIG,
    PAPER_HPARAMS,
    PAPER_RECIPE_CONFIG,
    RECIPES,
    TD3_RECIPES,
    TD7_CONFIG,
    TD7_CPU_CONFIG,
    TD7_CPU_HPARAMS,
    TD7_HPARAMS,
)
from rl_jax.agents.td3_update import (  # noqa: F401  (re-exported; bench reads the steps)
    _actor_and_target_step,
    _critic_step,
    add_to_buffer,
    init_buffer,
    metric_names,
    sample,
    update,
)
from rl_jax.training import (  # noqa: F401  (replay: bench reads td3.replay)
    networks,
    normalization,
    offpolicy,
    params,
    replay,
    validation,
)
from rl_jax.training.algorithm import RecipeBook
from rl_jax.training.offpolicy import OffPolicyConfig, TrainState


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(OffPolicyConfig):
    """Static settings of TD3/DDPG (the loop's are in ``OffPolicyConfig``)."""

    actor_hidden: tuple[int, ...] = (256, 256)  # hidden layer widths of the actor
    critic_hidden: tuple[int, ...] = (256, 256)  # hidden layer widths of each critic
    num_critics: int = 2  # TD3 2 (min of twins in the target); DDPG 1
    policy_delay: int = 2  # critic updates per actor + target update; DDPG 1
    network_init: str = "fan_in_uniform"  # see rl_jax.training.networks
    compute_dtype: str = "float32"  # matmul dtype ("bfloat16" trades precision for speed)
    # Rewards summed before bootstrapping: the critics learn from windows of n_step consecutive
    # steps of one env (cut at an episode's end), as DQN's n-step option. 1: the paper's TD3.
    n_step: int = 1
    actor_activation: str = "relu"  # hidden nonlinearity of the actor: relu, tanh or elu
    critic_activation: str = "relu"  # of the critics (TD7: elu)
    # "layer": a LayerNorm between each hidden linear layer of the critics and its nonlinearity,
    # which keeps Q-values bounded at high update rates (RLPD, BRO). "batch_renorm" (CrossQ):
    # batch renormalisation on the critics' input and after each hidden nonlinearity, training
    # mode in the critic update, evaluation mode (running statistics) for the actor's gradient
    # and the targets. "none": the paper's critics.
    critic_norm: str = "none"
    actor_norm: str = "none"  # the actor's: "none" or "layer"
    # critic_norm "batch_renorm": critic updates of plain batch norm (no r/d corrections) while
    # the running statistics settle (CrossQ's implementation: 100,000)
    renorm_warmup: int = 100_000
    # False (CrossQ): no target networks: the bootstrap uses the online actor (with target
    # smoothing) and critics, which see the batch's (s, a) and (s', a') in one forward pass, so
    # that batch renormalisation's statistics cover both. The target fields of the state are
    # then left at their initial values.
    target_networks: bool = True
    # Adam's first-moment decay for actor, critics and encoder (CrossQ: 0.5, so that the step
    # follows the latest gradients of a critic that has no target network to slow it; Adam's
    # default 0.9 otherwise). Written into the optimizer state with the rate at each step, so a
    # checkpoint records it and its state has the same fields at any value.
    adam_b1: float = 0.9
    # TD7's policy checkpoints: the training envs act with a frozen copy of the actor for an
    # assessment of checkpoint_episodes episodes (1 before env step checkpoint_episodes_from);
    # if none returned less than the checkpoint's score, the copy becomes the checkpoint, which
    # evaluation, best/ and loaded policies use; one episode below the score ends the assessment
    # early. Updates go on meanwhile (TD7 defers them: see rl_jax.agents.td3_agent).
    policy_checkpoints: bool = False
    checkpoint_episodes: int = 20  # policy_checkpoints: episodes per assessment (TD7: 20)
    # policy_checkpoints: env step from which assessments take checkpoint_episodes episodes
    # instead of 1 (TD7: 750,000 training steps)
    checkpoint_episodes_from: int = 750_000
    # "simba" (SimBa): observations standardised by running statistics, then for actor and
    # critics a linear layer, one pre-LayerNorm residual block per entry of actor_hidden /
    # critic_hidden (LN -> dense(4w) -> relu -> dense(w), plus the skip; the entries are the
    # width w, all equal), a LayerNorm and the output layer. "mlp": the paper's MLPs.
    network: str = "mlp"
    # Observations standardised by running statistics (as "simba" does) for the paper's MLPs too:
    # the statistics take in every observation acted on and go with the policy. Humanoid's
    # contact forces reach ~1,900 where most entries stay below 1, enough to saturate the tanh
    # of an actor that reads them raw (RESULTS.md, the Humanoid row).
    normalize_obs: bool = False
    # LAP (TD7): replay draws transitions with probability proportional to
    # max(|TD error|, 1)^lap_alpha (the larger of the critics' errors), without importance
    # weights, and the critics learn with LAP's Huber-like loss (quadratic below 1, linear above).
    lap: bool = False
    # SALE (TD7): an encoder learns embeddings z_s = f(s) and z_sa = g(z_s, a), g(f(s), a)
    # predicting f(s'); the actor reads [AvgL1Norm(linear(s)), z_s], the critics
    # [AvgL1Norm(linear(s, a)), z_sa, z_s], from a fixed copy of the encoder that is renewed with
    # the target networks (the targets read the copy before it). Needs n_step 1.
    sale: bool = False
    embedding_dim: int = 256  # sale: size of z_s and z_sa (TD7: 256)
    embedding_hidden: tuple[int, ...] = (256, 256)  # sale: hidden widths of f and of g
    # 0: the targets take a Polyak step of size tau after every actor update (TD3). N > 0: hard
    # copies every N updates instead (TD7: 250): target actor and critics <- online, SALE's
    # fixed target encoder <- fixed <- online, and LAP's new-transition priority resets to the
    # largest one stored.
    target_update_period: int = 0
    # TD7's value clipping: the bootstrap value min_i Q'(s', a') is clipped to the range of
    # targets seen up to the last target update (which renews it). Needs target_update_period.
    value_clipping: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.num_critics < 1 or self.policy_delay < 1 or self.n_step < 1:
            raise ValueError("num_critics, policy_delay and n_step must be >= 1")
        if self.network_init not in networks.INITS:
            raise ValueError(f"network_init must be one of {networks.INITS}")
        for name in ("actor_activation", "critic_activation"):
            if getattr(self, name) not in networks.ACTIVATIONS:
                raise ValueError(f"{name} must be one of {tuple(networks.ACTIVATIONS)}")
        if self.critic_norm not in networks.NORMS:
            raise ValueError(f"critic_norm must be one of {networks.NORMS}")
        if self.actor_norm not in ("none", "layer"):
            raise ValueError("actor_norm must be one of ('none', 'layer')")
        if self.network not in networks.ARCHITECTURES:
            raise ValueError(f"network must be one of {networks.ARCHITECTURES}")
        if self.network == "simba":
            self._check_simba()
        if self.checkpoint_episodes < 1 or self.checkpoint_episodes_from < 0:
            raise ValueError("checkpoint_episodes must be >= 1, checkpoint_episodes_from >= 0")
        if self.target_update_period < 0:
            raise ValueError("target_update_period must be >= 0 (0: Polyak steps)")
        if self.value_clipping and not self.target_update_period:
            raise ValueError("value_clipping needs target_update_period > 0 (it renews the range)")
        if self.sale and self.n_step != 1:
            raise ValueError("sale needs n_step 1: its encoder learns one-step dynamics")

    def _check_simba(self) -> None:
        for name in ("actor_hidden", "critic_hidden"):
            widths = getattr(self, name)
            if not widths or len(set(widths)) != 1:
                raise ValueError(f"network='simba' needs {name} of one width (w, w, ...)")
        if self.critic_norm != "none" or self.actor_norm != "none":
            raise ValueError("network='simba' has its own LayerNorms: leave the norms 'none'")

    @property
    def standardizes_obs(self) -> bool:
        """Whether the networks read observations standardised by running statistics."""
        return self.normalize_obs or self.network == "simba"

    @property
    def keeps_option_state(self) -> bool:
        """Whether an option keeps state beside the networks (an ``AgentWithOptions``)."""
        renorm = self.critic_norm == "batch_renorm"
        stateful = (
            self.sale,
            self.standardizes_obs,
            self.policy_checkpoints,
            self.value_clipping,
        )
        return any(stateful) or renorm


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: the TD3 paper's (code's) values."""

    actor_lr: Any = 3e-4  # Adam step size of the actor
    critic_lr: Any = 3e-4  # Adam step size of the critics
    gamma: Any = 0.99  # discount
    tau: Any = 0.005  # Polyak step of the target networks
    exploration_noise: Any = 0.1  # std of the Gaussian added to actions, x half-range
    # Step-to-step correlation rho of that noise, n_t = rho n_{t-1} + sqrt(1 - rho^2) eps_t (an
    # AR(1), i.e. discretised Ornstein-Uhlenbeck, process with the same std). 0: independent
    # noise, as in the TD3 paper. Near 1: slow pushes, as the original DDPG's OU noise; inertial
    # systems with a small time step need them, since independent noise averages out.
    exploration_correlation: Any = 0.0
    target_noise: Any = 0.2  # std of target policy smoothing, x half-range (0 turns it off)
    target_noise_clip: Any = 0.5  # smoothing noise clipped to +-this, x half-range
    # Env steps (all envs) over which both learning rates fall linearly to 0 (0: constant).
    lr_decay_steps: Any = 0.0
    lap_alpha: Any = 0.4  # lap: P(i) proportional to max(|TD error|, 1)^lap_alpha (TD7: 0.4)
    encoder_lr: Any = 3e-4  # sale: Adam step size of the encoder
    # policy_checkpoints: the checkpoint's score is multiplied by this when assessments lengthen
    # to checkpoint_episodes (TD7: 0.9)
    checkpoint_reset_weight: Any = 0.9


# ---- acting and init ----------------------------------------------------------------------------
def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The deterministic policy, in the env's own action units: the online actor, or with
    ``policy_checkpoints`` the checkpoint."""
    policy = agent.checkpoint.best if config.policy_checkpoints else current_policy(agent)
    return act_with(make_networks(config), policy, obs)


def explore(agent: Agent, obs, noise, key, config: Config, hparams: Hyperparams, clock=None):
    """``(actions, noise)``: the policy plus ``exploration_noise`` x half-range x an AR(1)
    noise of unit std (independent when ``exploration_correlation`` is 0), clipped to bounds.
    With ``policy_checkpoints`` the policy is the copy under assessment."""
    nets = make_networks(config)
    policy = agent.checkpoint.assessed if config.policy_checkpoints else current_policy(agent)
    action = act_with(nets, policy, obs)
    rho = hparams.exploration_correlation
    noise = rho * noise + jnp.sqrt(1.0 - rho**2) * jax.random.normal(key, action.shape)
    scaled = hparams.exploration_noise * row(nets.half_range, action) * noise
    return jnp.clip(action + scaled, row(nets.low, action), row(nets.high, action)), noise


def init_agent(key, config: Config, hparams: Hyperparams, obs_space, action_space) -> Agent:
    nets = make_networks(config)
    actor_key, critic_key = jax.random.split(key)
    obs = jnp.zeros(obs_space.shape, jnp.float32)
    action = jnp.zeros(action_space.shape, jnp.float32)
    # SALE's embeddings are inputs too (zeros shaped like them); without it, none.
    zs = (jnp.zeros(config.embedding_dim),) if config.sale else ()
    actor = nets.actor.init(actor_key, obs, *zs)
    extra = (jnp.zeros(2 * config.embedding_dim),) if config.sale else ()
    critics = networks.init_stacked(
        nets.critic, critic_key, config.num_critics, obs, action, *extra
    )
    # Batch renormalisation's statistics are state, not parameters: the optimizer never sees them.
    critics = dict(critics)
    critic_stats = critics.pop("batch_stats", None)
    adam = optax.inject_hyperparams(optax.adam)
    agent = Agent(
        actor=actor,
        critics=critics,
        target_actor=actor,
        target_critics=critics,
        actor_opt=adam(learning_rate=hparams.actor_lr).init(actor),
        critic_opt=adam(learning_rate=hparams.critic_lr).init(critics),
    )
    if not config.keeps_option_state:
        return agent
    # Keys derived apart from the split above, so the networks start as without the options.
    option_key = jax.random.fold_in(key, 1)
    agent = AgentWithOptions(
        **{field.name: getattr(agent, field.name) for field in dataclasses.fields(agent)},
        encoders=_init_encoders(option_key, nets, obs, action, hparams) if config.sale else None,
        obs_stats=normalization.init(obs.shape[-1]) if config.standardizes_obs else None,
        critic_stats=critic_stats,
        value_range=ValueRange.initial() if config.value_clipping else None,
    )
    if config.policy_checkpoints:
        checkpoint = init_checkpoint(agent, config.num_envs, config.learning_starts)
        agent = agent.replace(checkpoint=checkpoint)
    return agent


def _init_encoders(key, nets: Networks, obs, action, hparams: Hyperparams) -> Encoders:
    online = nets.encoder.init(key, obs, action)
    opt = optax.inject_hyperparams(optax.adam)(learning_rate=hparams.encoder_lr).init(online)
    return Encoders(online=online, fixed=online, fixed_target=online, opt=opt)


LEARNER = offpolicy.Learner(
    init_agent,
    explore,
    act,
    update,
    metric_names,
    init_buffer,
    add_to_buffer,
    observe,
)


# ---- the Algorithm objects ------------------------------------------------------------------
class TD3Family(RecipeBook):
    """TD3 or DDPG as an ``rl_jax.training.algorithm.Algorithm``; the two differ only in their
    settings."""

    recipes = TD3_RECIPES
    ranges = {
        "renorm_warmup": validation.NON_NEGATIVE,
        "adam_b1": validation.Range(0.0, 1.0, high_open=True),
        "lap_alpha": validation.UNIT,
        "target_update_period": validation.NON_NEGATIVE,
        "embedding_dim": validation.AT_LEAST_ONE,
        "checkpoint_episodes": validation.AT_LEAST_ONE,
        "checkpoint_episodes_from": validation.NON_NEGATIVE,
        "checkpoint_reset_weight": validation.NON_NEGATIVE,
    }

    def __init__(self, name: str, config_type: type, hparams_type: type):
        self.name = name
        self.config_type, self.hparams_type = config_type, hparams_type

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        return offpolicy.init(LEARNER, key, config, hparams)

    def train_chunk(self, state: TrainState, config: Config, hparams: Hyperparams):
        return offpolicy.train_chunk(LEARNER, state, config, hparams)

    def spread_runs(self, config: Config) -> bool:
        """Networks of width <= 64 spread over every device, padded if need be. Measured with 64
        x 64 networks (Pendulum, batch 256): 5 seeds did 4,244-4,279 updates/s as 3 + 3 on 2
        devices against 3,253-3,358 on one; at 256 x 256 one device was as fast or faster
        (BENCHMARKS.md, TD3 section 1)."""
        return max((*config.actor_hidden, *config.critic_hidden)) <= 64

    def policy(self, state: TrainState, config: Config):
        """``obs -> action`` (env units) of the deterministic policy of one seed's state."""
        agent = state.agent
        return lambda obs: act(agent, obs, config)


@dataclasses.dataclass(frozen=True, kw_only=True)
class DDPGConfig(Config):
    """DDPG's defaults: one critic, updated with the actor at every step."""

    num_critics: int = 1
    policy_delay: int = 1


@struct.dataclass
class DDPGHyperparams(Hyperparams):
    """DDPG's defaults: no target policy smoothing."""

    target_noise: Any = 0.0


td3 = TD3Family("td3", Config, Hyperparams)
ddpg = TD3Family("ddpg", DDPGConfig, DDPGHyperparams)
