"""One SAC update: a batch from the replay (one-step transitions or n-step windows), a critic
step (then a Polyak step of the target critics), and every ``policy_delay``-th update an actor
step and a temperature step. ``config``/``hparams`` are ``sac.Config``/``sac.Hyperparams``.

Order within an update, as in the paper's algorithm: the critics learn first (their target
reads the temperature and actor from before this update), then the actor against the updated
critics, then the temperature from the log-densities of the actions the actor step drew.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from rl_jax.agents.actor_critic import CriticBatch, every_policy_delay, gather_batch
from rl_jax.agents.common import optimizer_step, polyak_update
from rl_jax.agents.sac_config import Agent, Config, Hyperparams
from rl_jax.agents.sac_losses import actor_loss_fn, critic_loss_fn, temperature_loss
from rl_jax.agents.sac_networks import Networks, make_networks
from rl_jax.training import normalization, replay, squashed_gaussian
from rl_jax.training.replay import ReplayBuffer, Transition

# Every numeric argument of Adam (b1 too) sits in each injected state from its init; the step
# reads them there, so one transformation serves actor, critics and temperature.
_ADAM = optax.inject_hyperparams(optax.adam)(learning_rate=3e-4)


def sample(
    buffer: ReplayBuffer[Transition], key, config: Config, hparams: Hyperparams
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


def critic_step(agent: Agent, batch: CriticBatch, key, hparams: Hyperparams, nets: Networks):
    """``(agent, loss, CriticAux)`` after one critic step and, with target networks, a Polyak
    step of the targets (and, under batch renormalisation, the batch's statistics folded in)."""
    (loss, aux), grads = jax.value_and_grad(critic_loss_fn, has_aux=True)(
        agent.critics,
        agent.target_critics,
        agent.actor,
        batch,
        key,
        alpha_of(agent),
        nets,
        agent.critic_stats,
        agent.actor_stats,
    )
    critics, critic_opt = optimizer_step(
        _ADAM, grads, agent.critic_opt, agent.critics, learning_rate=hparams.critic_lr
    )
    agent = agent.replace(critics=critics, critic_opt=critic_opt, critic_stats=aux.stats)
    if agent.target_critics is not None:
        agent = agent.replace(
            target_critics=polyak_update(agent.target_critics, critics, hparams.tau)
        )
    return agent, loss, aux


def actor_and_temperature_step(agent: Agent, obs, key, config, hparams: Hyperparams, nets):
    """``(agent, (actor loss, temperature loss, entropy estimate))`` after an actor step and,
    with ``learn_temperature``, a step of ``log_alpha`` towards the target entropy."""
    inputs = (agent.critics, obs, key, alpha_of(agent), nets, agent.actor_stats)
    (loss, (log_pi, stats)), grads = jax.value_and_grad(actor_loss_fn, has_aux=True)(
        agent.actor, *inputs, agent.critic_stats
    )
    actor, actor_opt = optimizer_step(
        _ADAM, grads, agent.actor_opt, agent.actor, learning_rate=hparams.actor_lr
    )
    agent = agent.replace(actor=actor, actor_opt=actor_opt, actor_stats=stats)
    target_entropy = hparams.target_entropy_per_dim * nets.low.shape[0]
    alpha_loss, alpha_grad = jax.value_and_grad(temperature_loss)(
        agent.log_alpha, log_pi, target_entropy
    )
    if config.learn_temperature:
        log_alpha, alpha_opt = optimizer_step(
            _ADAM, alpha_grad, agent.alpha_opt, agent.log_alpha, learning_rate=hparams.alpha_lr
        )
        agent = agent.replace(log_alpha=log_alpha, alpha_opt=alpha_opt)
    return agent, (loss, alpha_loss, squashed_gaussian.entropy_estimate(log_pi))


def update(
    agent: Agent,
    buffer: ReplayBuffer[Transition],
    key,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
):
    """One critic update; every ``policy_delay``-th also an actor and temperature update."""
    nets = make_networks(config)
    sample_key, critic_key, actor_key = jax.random.split(key, 3)
    batch = normalized_batch(agent, sample(buffer, sample_key, config, hparams))
    agent, critic_loss, aux = critic_step(agent, batch, critic_key, hparams, nets)

    def policy_step(agent):
        return actor_and_temperature_step(agent, batch.obs, actor_key, config, hparams, nets)

    agent, (actor_loss, alpha_loss, entropy) = every_policy_delay(
        update_index, config.policy_delay, policy_step, agent
    )
    metrics = {
        "critic_loss": critic_loss,
        "actor_loss": actor_loss,
        "alpha_loss": alpha_loss,
        "alpha": jnp.exp(agent.log_alpha),
        "entropy": entropy,
        "q": jnp.mean(aux.q_tm1),
    }
    return agent, buffer, metrics


#: The keys of ``update``'s metrics.
metric_names = ("critic_loss", "actor_loss", "alpha_loss", "alpha", "entropy", "q")
