"""What the learners share of their maths: the optimizer step at this update's rates, rate
schedules, gradient clipping and target-network steps.

The envs they train and evaluate on, and the evaluation itself, are in
``rl_jax.training.episodes`` (the off-policy loop uses them too).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from jax.typing import ArrayLike


def optimizer_step(
    optimizer: optax.GradientTransformation,
    grads: optax.Updates,
    opt_state: optax.InjectStatefulHyperparamsState,
    params: optax.Params,
    **rates: ArrayLike,
) -> tuple[optax.Params, optax.InjectStatefulHyperparamsState]:
    """One step of an ``optax.inject_hyperparams`` optimizer at ``rates`` (this update's values of
    its hyperparameters, e.g. a decayed learning rate): ``(new params, new opt_state)``. The
    rates are written into the state first, so a checkpoint holds the rates in use."""
    opt_state = opt_state._replace(hyperparams={**opt_state.hyperparams, **rates})
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state


def injected_step(
    factory: Callable[..., optax.GradientTransformation],
    grads: optax.Updates,
    opt_state: optax.InjectStatefulHyperparamsState,
    params: optax.Params,
    **rates: ArrayLike,
) -> tuple[optax.Params, optax.InjectStatefulHyperparamsState]:
    """``optimizer_step`` of ``optax.inject_hyperparams(factory)`` built at this update's
    ``rates``, so that no optimizer stands at rates it never uses; ``opt_state`` is what the same
    optimizer, built at the run's first rates, initialised."""
    optimizer = optax.inject_hyperparams(factory)(**rates)
    return optimizer_step(optimizer, grads, opt_state, params, **rates)


def clip_by_global_norm(
    grads: optax.Updates, max_norm: ArrayLike
) -> tuple[optax.Updates, jax.Array]:
    """``(grads scaled to global norm <= max_norm, norm before)``; ``max_norm <= 0`` keeps them."""
    norm = optax.tree.norm(grads)
    scale = jnp.where(max_norm > 0.0, jnp.minimum(1.0, max_norm / jnp.maximum(norm, 1e-12)), 1.0)
    return jax.tree.map(lambda g: g * scale, grads), norm


def clipped_adam(
    learning_rate: ArrayLike, max_grad_norm: ArrayLike, adam_eps: ArrayLike
) -> optax.GradientTransformation:
    """Adam with its epsilon after clipping the gradients to a global norm: the optimizer of the
    learners whose papers set Adam's epsilon (C51, QR-DQN, R2D2), as an
    ``optax.inject_hyperparams`` factory of those three rates."""
    return optax.chain(
        optax.clip_by_global_norm(max_grad_norm), optax.adam(learning_rate, eps=adam_eps)
    )


def linearly_decayed(rate: ArrayLike, progress: ArrayLike, decay_length: ArrayLike) -> jax.Array:
    """``rate`` falling linearly to 0 over ``decay_length`` (env steps or updates, as
    ``progress``; constant if the length is <= 0). A rate that ends at 0 freezes the policy a run
    has converged to, instead of leaving the last updates to move it around a good solution."""
    fraction = jnp.clip(1.0 - progress / jnp.maximum(decay_length, 1.0), 0.0, 1.0)
    return rate * jnp.where(decay_length > 0.0, fraction, 1.0)


def polyak_update(target: optax.Params, online: optax.Params, tau: ArrayLike) -> optax.Params:
    """``target <- (1 - tau) * target + tau * online``, leaf by leaf."""
    return jax.tree.map(lambda t, o: (1.0 - tau) * t + tau * o, target, online)
