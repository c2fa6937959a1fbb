"""TD3 (Fujimoto et al. 2018) and DDPG (that paper's "our DDPG" baseline).

What tells them apart is settings only: TD3 uses ``num_critics=2`` (clipped double Q: the target
takes the min of twin target critics), ``policy_delay=2`` (actor and target networks update after
every second critic update) and ``target_noise=0.2`` clipped at ``0.5`` (target policy smoothing);
DDPG is ``num_critics=1``, ``policy_delay=1``, ``target_noise=0``.

One update: a uniform batch from the replay (of n-step windows with ``n_step`` > 1), a critic
step towards ``r + gamma * min_i Q'_i(s', smoothed pi'(s'))``, and every ``policy_delay``-th an
actor step up the first critic and a Polyak step of the targets. The network settings (LayerNorm,
SimBa blocks, standardised observations) change the networks, not the update.

Usage (one seed; ``rl_jax.training.parallel`` runs seeds x hyperparameters as one program)::

    config = td3.default_config("rl_jax/Pendulum-v1")          # static, frozen
    hparams = td3.default_hyperparams("rl_jax/Pendulum-v1")     # arrays, vmappable
    state = td3.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(td3.train_chunk, static_argnums=1)
    state, metrics = chunk(state, config, hparams)              # metrics.eval_return, ...
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax.agents import actor_critic
from rl_jax.agents.actor_critic import (
    ActorCriticConfig,
    ActorCriticHyperparams,
    CriticBatch,
    Networks,
    Rate,
    critic_values,
    first_critic_value,
)
from rl_jax.agents.common import injected_step, linearly_decayed, polyak_update
from rl_jax.envs.core.spaces import Space
from rl_jax.training import episodes, networks, normalization, offpolicy, replay
from rl_jax.training.networks import Params
from rl_jax.training.normalization import RunningStats
from rl_jax.training.offpolicy import Clock
from rl_jax.training.params import Scalar
from rl_jax.training.recipes import Recipe, Recipes, Setting
from rl_jax.training.replay import ReplayBuffer, Transition


def _moved_to(learner: str, **off: Any) -> dict[str, tuple[Any, str]]:
    """``RETIRED`` entries: each setting at the value that meant off, now ``learner``'s."""
    return {name: (value, f"is now the {learner} learner's") for name, value in off.items()}


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(ActorCriticConfig):
    """Static settings of TD3/DDPG (the shared ones are ``ActorCriticConfig``'s)."""

    # Rewards summed before bootstrapping: the critics learn from windows of n_step consecutive
    # steps of one env (cut at an episode's end), as DQN's n-step option. 1: the paper's TD3.
    n_step: int = 1
    # "layer": a LayerNorm between each hidden linear layer of the critics and its nonlinearity,
    # which keeps Q-values bounded at high update rates (RLPD, BRO). "none": the paper's critics.
    critic_norm: networks.Norm = "none"
    actor_norm: networks.Norm = "none"  # the actor's: "none" or "layer"
    # "simba" (SimBa): observations standardised by running statistics, then for actor and
    # critics a linear layer, one pre-LayerNorm residual block per entry of actor_hidden /
    # critic_hidden (LN -> dense(4w) -> relu -> dense(w), plus the skip; the entries are the
    # width w, all equal), a LayerNorm and the output layer. "mlp": the paper's MLPs.
    network: networks.Architecture = "mlp"
    # Observations standardised by running statistics (as "simba" does) for the paper's MLPs too:
    # the statistics take in every observation acted on and go with the policy. Observations
    # whose entries differ in scale by orders of magnitude (Humanoid's contact forces) need it.
    normalize_obs: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.n_step < 1:
            raise ValueError("n_step must be >= 1")
        for name in ("critic_norm", "actor_norm"):
            if getattr(self, name) not in ("none", "layer"):
                raise ValueError(f"{name} must be one of ('none', 'layer')")
        hidden = {"actor_hidden": self.actor_hidden, "critic_hidden": self.critic_hidden}
        networks.check_architecture(self.network, hidden, (self.critic_norm, self.actor_norm))

    #: Run-directory migration (``params.dataclass_from_dict``): old runs recorded these.
    RETIRED: ClassVar[dict[str, tuple[Any, str]]] = {
        **_moved_to(
            "td7",
            sale=False,
            lap=False,
            value_clipping=False,
            policy_checkpoints=False,
            target_update_period=0,
            embedding_dim=256,
            embedding_hidden=[256, 256],
            checkpoint_episodes=20,
            checkpoint_episodes_from=750_000,
        ),
        **_moved_to("crossq", target_networks=True, adam_b1=0.9, renorm_warmup=100_000),
    }

    @property
    def standardizes_obs(self) -> bool:
        """Whether the networks read observations standardised by running statistics."""
        return self.normalize_obs or self.network == "simba"


@struct.dataclass
class Hyperparams(ActorCriticHyperparams):
    """TD3's hyperparameters: the shared ones and the targets' Polyak step."""

    tau: Scalar = 0.005  # Polyak step of the target networks

    #: Run-directory migration (``params.dataclass_from_dict``): old runs recorded these.
    RETIRED: ClassVar[dict[str, tuple[Any, str]]] = _moved_to(
        "td7", lap_alpha=0.4, encoder_lr=3e-4, checkpoint_reset_weight=0.9
    )


@struct.dataclass
class Agent:
    """Parameters, targets, optimizer states and, where kept, observation statistics."""

    actor: Params  # actor parameters
    critics: Params  # critic parameters, leaves [num_critics, ...]
    target_actor: Params
    target_critics: Params
    actor_opt: optax.OptState  # inject_hyperparams(adam) state: holds the learning rate
    critic_opt: optax.OptState
    # standardizes_obs: the running statistics of the observations acted on (None otherwise)
    obs_stats: RunningStats | None = None


@functools.lru_cache(maxsize=64)
def make_networks(config: Config) -> Networks:
    """The networks for ``config.env_id`` (cached: called at every trace)."""
    action_space = episodes.action_space(config)
    box = actor_critic.bounded_box(action_space, "TD3/DDPG")
    low, high = actor_critic.bounds(box, "TD3/DDPG")
    dtype = jnp.dtype(config.compute_dtype)
    actor_layers = networks.Layers(
        hidden=config.actor_hidden,
        activation=config.actor_activation,
        initializer=config.network_init,
        norm=config.actor_norm,
        architecture=config.network,
        dtype=dtype,
    )
    critic_layers = networks.Layers(
        hidden=config.critic_hidden,
        activation=config.critic_activation,
        initializer=config.network_init,
        norm=config.critic_norm,
        architecture=config.network,
        dtype=dtype,
    )
    actor = networks.Actor(layers=actor_layers, action_low=low, action_high=high)
    critic = networks.Critic(layers=critic_layers)
    return Networks(actor, critic, box.low.copy(), box.high.copy())


# ---- acting -------------------------------------------------------------------------------------
def policy_action(nets: Networks, agent: Agent, obs: jax.Array) -> jax.Array:
    """The deterministic policy of ``agent``, in the env's own action units."""
    obs = normalization.normalize(agent.obs_stats, obs)
    return actor_critic.actor_action(nets, agent.actor, obs)


def act(agent: Agent, obs: jax.Array, config: Config) -> jax.Array:
    """The deterministic policy, in the env's own action units."""
    return policy_action(make_networks(config), agent, obs)


def explore(
    agent: Agent,
    obs: jax.Array,
    noise: jax.Array,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    clock: Clock,
) -> tuple[jax.Array, jax.Array]:
    """``(actions, noise)``: the policy plus AR(1) exploration noise, clipped to the bounds."""
    nets = make_networks(config)
    action = policy_action(nets, agent, obs)
    return actor_critic.explore(action, noise, key, nets, hparams)


def observe(
    agent: Agent,
    transitions: Transition,
    episode_return: jax.Array,
    done: jax.Array,
    clock: Clock,
    config: Config,
    hparams: Hyperparams,
) -> Agent:
    """Every env step: the running statistics (kept with ``standardizes_obs``) take in the
    observations acted on."""
    if agent.obs_stats is None:
        return agent
    mask = jnp.ones(transitions.obs.shape[:1], jnp.float32)
    return dataclasses.replace(
        agent, obs_stats=normalization.update(agent.obs_stats, transitions.obs, mask)
    )


def init_agent(
    key: jax.Array, config: Config, hparams: Hyperparams, obs_space: Space, action_space: Space
) -> Agent:
    """A fresh agent: targets copies of the actor and critics."""
    nets = make_networks(config)
    actor_key, critic_key = jax.random.split(key)
    obs = jnp.zeros(obs_space.shape, jnp.float32)
    action = jnp.zeros(action_space.shape, jnp.float32)
    actor = nets.actor.init(actor_key, obs)
    critics = dict(networks.init_stacked(nets.critic, critic_key, config.num_critics, obs, action))
    adam = optax.inject_hyperparams(optax.adam)
    obs_stats = normalization.init(obs.shape[-1]) if config.standardizes_obs else None
    return Agent(
        actor=actor,
        critics=critics,
        target_actor=actor,
        target_critics=critics,
        actor_opt=adam(learning_rate=hparams.actor_lr).init(actor),
        critic_opt=adam(learning_rate=hparams.critic_lr).init(critics),
        obs_stats=obs_stats,
    )


# ---- losses -------------------------------------------------------------------------------------
def critic_loss_fn(
    critics: Params,
    agent: Agent,
    batch: CriticBatch,
    noise: jax.Array,
    hparams: Hyperparams,
    nets: Networks,
) -> tuple[jax.Array, jax.Array]:
    """``(loss, q_tm1 [C, B])``: the critics' mean squared error to the clipped double-Q target
    of the target networks (``noise`` [B, action_dim], standard normal, smooths the target
    action)."""
    a_t = actor_critic.actor_action(nets, agent.target_actor, batch.next_obs)
    a_t = actor_critic.target_action(a_t, noise, hparams, nets)
    q_t = critic_values(nets, agent.target_critics, batch.next_obs, a_t)
    q_tm1 = critic_values(nets, critics, batch.obs, batch.action)
    return actor_critic.critic_loss(q_tm1, batch.r_t, batch.discount_t, q_t), q_tm1


def actor_loss_fn(actor: Params, critics: Params, obs: jax.Array, nets: Networks) -> jax.Array:
    """Deterministic policy gradient through the *first* critic only (as TD3 prescribes)."""
    action = actor_critic.actor_action(nets, actor, obs)
    return actor_critic.deterministic_policy_loss(first_critic_value(nets, critics, obs, action))


# ---- one update ---------------------------------------------------------------------------------
def critic_step(
    agent: Agent,
    batch: CriticBatch,
    key: jax.Array,
    hparams: Hyperparams,
    nets: Networks,
    rate: Rate,
) -> tuple[Agent, jax.Array, jax.Array]:
    """``(agent, loss, q_tm1)`` after one Adam step of the critics; ``rate`` decays a rate."""
    noise = jax.random.normal(key, batch.action.shape, jnp.float32)
    (loss, q_tm1), grads = jax.value_and_grad(critic_loss_fn, has_aux=True)(
        agent.critics, agent, batch, noise, hparams, nets
    )
    critics, critic_opt = injected_step(
        optax.adam, grads, agent.critic_opt, agent.critics, learning_rate=rate(hparams.critic_lr)
    )
    return dataclasses.replace(agent, critics=critics, critic_opt=critic_opt), loss, q_tm1


def actor_step(
    agent: Agent, obs: jax.Array, hparams: Hyperparams, nets: Networks, rate: Rate
) -> tuple[Agent, jax.Array]:
    """``(agent, loss)`` after an Adam step of the actor and a Polyak step of the targets."""
    loss, grads = jax.value_and_grad(actor_loss_fn)(agent.actor, agent.critics, obs, nets)
    actor, actor_opt = injected_step(
        optax.adam, grads, agent.actor_opt, agent.actor, learning_rate=rate(hparams.actor_lr)
    )
    agent = dataclasses.replace(
        agent,
        actor=actor,
        actor_opt=actor_opt,
        target_actor=polyak_update(agent.target_actor, actor, hparams.tau),
        target_critics=polyak_update(agent.target_critics, agent.critics, hparams.tau),
    )
    return agent, loss


def update(
    agent: Agent,
    buffer: ReplayBuffer[Transition],
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
) -> tuple[Agent, ReplayBuffer[Transition], dict[str, jax.Array]]:
    """One critic update; every ``policy_delay``-th also an actor and target update."""
    nets = make_networks(config)
    sample_key, noise_key = jax.random.split(key)
    rows, columns = replay.sample_indices(buffer, sample_key, config.batch_size)
    batch = actor_critic.gather_batch(buffer, rows, columns, hparams.gamma, config.n_step)
    if agent.obs_stats is not None:
        normalize = functools.partial(normalization.normalize, agent.obs_stats)
        batch = batch._replace(obs=normalize(batch.obs), next_obs=normalize(batch.next_obs))
    env_steps = offpolicy.env_steps_at_update(update_index, config)

    def rate(value: Scalar) -> jax.Array:
        return linearly_decayed(value, env_steps, hparams.lr_decay_steps)

    agent, critic_loss, q_tm1 = critic_step(agent, batch, noise_key, hparams, nets, rate)
    agent, actor_loss = actor_critic.every_policy_delay(
        update_index,
        config.policy_delay,
        lambda agent: actor_step(agent, batch.obs, hparams, nets, rate),
        agent,
    )
    return agent, buffer, {"critic_loss": critic_loss, "actor_loss": actor_loss, "q": q_tm1.mean()}


LEARNER = offpolicy.Learner(
    init_agent, explore, act, update, ("critic_loss", "actor_loss", "q"), observe=observe
)


# ---- recipes ------------------------------------------------------------------------------------
# Each env's default on top of the paper's settings (the Config/Hyperparams defaults), and named
# alternatives, each with the reason it was chosen (rl_jax.training.recipes). How they were chosen:
# docs/learners/td3.md#how-the-recipes-were-chosen.

# The classic envs: small networks suffice, one update per env step as in the paper.
PENDULUM_CONFIG: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 250,
    "learning_starts": 1000,
    "actor_hidden": (64, 64),
    "critic_hidden": (64, 64),
}
# The rocket and its settle variant: the Pendulum loop with 5,000-step chunks (10 episodes).
ROCKET_CONFIG: dict[str, Setting] = {
    **PENDULUM_CONFIG,
    "iterations_per_chunk": 1250,
    "learning_starts": 2000,
}
# Rocket: a longer horizon, and exploration noise that pushes long enough to move the velocity
# (docs/learners/td3.md#how-the-recipes-were-chosen).
ROCKET_HPARAMS: dict[str, float] = {
    "gamma": 0.995,
    "exploration_correlation": 0.98,
    "exploration_noise": 0.5,
}
# Half cheetah's CPU loop: one update per env step, cheaper ones, since on a CPU updates are the
# cost (docs/learners/td3.md#how-the-recipes-were-chosen).
CHEETAH_LOOP: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 1250,  # eval every 5,000 env steps per seed
    "batch_size": 128,
    "learning_starts": 10_000,
}
# Half cheetah's default: 128 x 128 at rate 1e-3, chosen by return against wall-clock
# (RESULTS.md#td3-on-half-cheetah-in-minutes).
FAST_CHEETAH_CONFIG: dict[str, Setting] = {"actor_hidden": (128, 128), "critic_hidden": (128, 128)}
FAST_CHEETAH_HPARAMS: dict[str, float] = {"actor_lr": 1e-3, "critic_lr": 1e-3}
# The rest of the MuJoCo suite runs half cheetah's recipe unchanged, so that the suite's results
# say what one recipe does on each task.
CHEETAH_CPU_CONFIG: dict[str, Setting] = {**CHEETAH_LOOP, **FAST_CHEETAH_CONFIG}
MUJOCO_SUITE = tuple(
    f"rl_jax/{name}-v5" for name in ("Hopper", "Walker2d", "Ant", "Reacher", "Swimmer", "Humanoid")
)
# Humanoid: raw contact forces beside joint angles saturate the actor's tanh unless standardised.
HUMANOID_CONFIG: dict[str, Setting] = {**CHEETAH_CPU_CONFIG, "normalize_obs": True}
#: The per-env config settings above, by env id (what each env's ``default`` recipe starts from).
ENV_CONFIGS: dict[str, dict[str, Setting]] = {
    "rl_jax/Pendulum-v1": PENDULUM_CONFIG,
    "rl_jax/Rocket-v0": ROCKET_CONFIG,
    "rl_jax/RocketSettle-v0": ROCKET_CONFIG,
    "rl_jax/HalfCheetah-v5": CHEETAH_LOOP,
    **{env_id: CHEETAH_CPU_CONFIG for env_id in MUJOCO_SUITE if env_id != "rl_jax/Humanoid-v5"},
    "rl_jax/Humanoid-v5": HUMANOID_CONFIG,
}
# The TD3 paper's own loop: one env, one update per env step, batch 256, 25k warm-up steps.
PAPER_CONFIG: dict[str, Setting] = {
    "num_envs": 1,
    "updates_per_iteration": 1,
    "iterations_per_chunk": 5000,
    "batch_size": 256,
    "learning_starts": 25_000,
}
# The TD3 paper's whole recipe on any env: its loop above, its 256 x 256 networks and its rates
# (the Config and Hyperparams defaults, restated because the MuJoCo suite's recipes change them).
PAPER_RECIPE_CONFIG: dict[str, Setting] = {
    **PAPER_CONFIG,
    "actor_hidden": (256, 256),
    "critic_hidden": (256, 256),
}
PAPER_HPARAMS: dict[str, Setting] = {"actor_lr": 3e-4, "critic_lr": 3e-4}
# The settings of the TD3 paper's own runs (2018), which made the curves our results compare with
# (RESULTS.md#two-paper-recipes-on-hopper); 10,000 random steps on PAPER_2018_LONG_WARMUP.
PAPER_2018_CONFIG: dict[str, Setting] = {
    **PAPER_CONFIG,
    "batch_size": 100,
    "learning_starts": 1_000,
    "actor_hidden": (400, 300),
    "critic_hidden": (400, 300),
}
PAPER_2018_HPARAMS: dict[str, Setting] = {"actor_lr": 1e-3, "critic_lr": 1e-3}
# Half cheetah on one GPU (MJX), where more envs and larger batches cost little more time; chosen
# by return against wall-clock (docs/learners/td3.md#how-the-recipes-were-chosen).
GPU_CHEETAH_CONFIG: dict[str, Setting] = {
    **FAST_CHEETAH_CONFIG,
    "num_envs": 64,
    "batch_size": 1024,
    "updates_per_iteration": 32,
    "iterations_per_chunk": 384,  # 24,576 env steps per seed between evaluations
    "buffer_size": 500_000,
}
PAPER_2018_LONG_WARMUP = ("rl_jax/HalfCheetah-v5", "rl_jax/Ant-v5")
CHEETAH = "rl_jax/HalfCheetah-v5"
# The inverted double pendulum: one update per env step in 4 envs, the paper's evaluation interval.
_DOUBLE_PENDULUM = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 1_250,
    "learning_starts": 10_000,
    "buffer_size": 200_000,  # the whole run (x seeds) fits in memory with room to spare
}

#: TD3's recipes (DDPG's too: its own defaults differ, its recipes are these).
RECIPES = Recipes(
    Recipe(
        "default",
        "64x64 networks, 4 envs x 4 updates per iteration",
        PENDULUM_CONFIG,
        envs=("rl_jax/Pendulum-v1",),
        # measured: docs/learners/td3.md#how-the-recipes-were-chosen (as every throughput below)
        throughput=(830.0, 5),
    ),
    Recipe(
        "default",
        "the Pendulum loop, gamma 0.995, AR(1) exploration noise (rho 0.98, std 0.5)",
        {**ROCKET_CONFIG, "iterations_per_chunk": 625},
        ROCKET_HPARAMS,
        envs=("rl_jax/Rocket-v0", "rl_jax/RocketSettle-v0"),
    ),
    Recipe(
        "default",
        "the paper's networks, 4 envs x 4 updates per iteration, 10,000 warm-up steps",
        _DOUBLE_PENDULUM,
        envs=("rl_jax/InvertedDoublePendulum-v5",),
    ),
    Recipe(
        "default",
        "128x128 at rate 1e-3, batch 128, 4 envs x 4 updates, 10,000 warm-up steps",
        CHEETAH_CPU_CONFIG,
        FAST_CHEETAH_HPARAMS,
        envs=(CHEETAH,),
        throughput=(280.0, 5),
    ),
    Recipe(
        "default",
        "half cheetah's CPU recipe: 128x128 at rate 1e-3, batch 128, 4 envs x 4 updates",
        CHEETAH_CPU_CONFIG,
        FAST_CHEETAH_HPARAMS,
        envs=tuple(env_id for env_id in MUJOCO_SUITE if env_id != "rl_jax/Humanoid-v5"),
    ),
    Recipe(
        "default",
        "half cheetah's CPU recipe, observations standardised by running statistics",
        HUMANOID_CONFIG,
        FAST_CHEETAH_HPARAMS,
        envs=("rl_jax/Humanoid-v5",),
    ),
    Recipe(
        "paper-width",
        "the paper's 256x256 networks at rate 3e-4 in the CPU loop",
        CHEETAH_LOOP,
        envs=(CHEETAH,),
        throughput=(96.0, 5),
    ),
    Recipe(
        "paper",
        "the TD3 repository's recipe since 2019: 256x256 at rate 3e-4, one env, batch 256, "
        "25,000 warm-up steps",
        PAPER_RECIPE_CONFIG,
        PAPER_HPARAMS,
    ),
    Recipe(
        "paper-2018",
        "the settings of the TD3 paper's own runs: 400x300 at rate 1e-3, one env, batch 100, "
        "1,000 warm-up steps",
        PAPER_2018_CONFIG,
        PAPER_2018_HPARAMS,
    ),
    Recipe(
        "paper-2018",
        "the settings of the TD3 paper's own runs: 400x300 at rate 1e-3, one env, batch 100, "
        "10,000 warm-up steps",
        {**PAPER_2018_CONFIG, "learning_starts": 10_000},
        PAPER_2018_HPARAMS,
        envs=PAPER_2018_LONG_WARMUP,
    ),
    Recipe(
        "gpu",
        "for one GPU (MJX): 64 envs per seed, batch 1,024, 32 updates per iteration",
        {**CHEETAH_LOOP, **GPU_CHEETAH_CONFIG},
        FAST_CHEETAH_HPARAMS,
        envs=(CHEETAH,),
        total_steps=250_000,
    ),
)


# ---- the Algorithm objects ----------------------------------------------------------------------
class TD3Family(offpolicy.OffPolicyAlgorithm[Config]):
    """TD3 or DDPG as an ``rl_jax.training.algorithm.Algorithm``; the two differ only in their
    settings' defaults."""

    recipes = RECIPES
    learner = LEARNER

    def __init__(self, name: str, config_type: type[Config], hparams_type: type[Hyperparams]):
        self.name = name
        self.config_type, self.hparams_type = config_type, hparams_type


@dataclasses.dataclass(frozen=True, kw_only=True)
class DDPGConfig(Config):
    """DDPG's defaults: one critic, updated with the actor at every step."""

    num_critics: int = 1
    policy_delay: int = 1


@struct.dataclass
class DDPGHyperparams(Hyperparams):
    """DDPG's defaults: no target policy smoothing."""

    target_noise: Scalar = 0.0


td3 = TD3Family("td3", Config, Hyperparams)
ddpg = TD3Family("ddpg", DDPGConfig, DDPGHyperparams)
