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

import jax
import jax.numpy as jnp
import optax

from rl_jax.agents.sac_config import Agent, Config, Hyperparams
from rl_jax.agents.sac_networks import (
    actor_outputs,
    deterministic_action,
    make_networks,
    sampled_action,
)
from rl_jax.agents.sac_recipes import RECIPES
from rl_jax.agents.sac_update import metric_names, update
from rl_jax.training import networks, normalization, offpolicy, validation
from rl_jax.training.replay import Transition


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
class SAC(offpolicy.OffPolicyAlgorithm[Config]):
    """SAC as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "sac"
    config_type = Config
    hparams_type = Hyperparams
    recipes = RECIPES
    learner = LEARNER
    ranges = {
        "renorm_warmup": validation.NON_NEGATIVE,
        "adam_b1": validation.Range(0.0, 1.0, high_open=True),
        "initial_alpha": validation.POSITIVE,
    }


sac = SAC()
