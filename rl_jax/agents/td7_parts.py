"""TD7's parts (Fujimoto et al. 2023, "For SALE: State-Action Learned Embeddings"): the pure maths
of the ``td7`` learner (``rl_jax.agents.td7``), the state it keeps beside its networks, SALE's
embeddings of a fixed encoder and LAP's replay.

* LAP, loss-adjusted prioritized replay (Fujimoto, Meger and Precup 2020, "An Equivalence between
  Loss Functions and Non-Uniform Sampling in Experience Replay"): transitions are drawn with
  probability proportional to ``max(|td|, 1)^alpha`` (the sum tree of
  ``rl_jax.training.prioritized``), without importance weights, and the critics learn with a
  Huber-like loss whose quadratic part stops at the same threshold 1. Sampling by priority and
  the loss's linear part together give an unbiased equivalent of the mean squared error on
  uniform data; the floor of 1 keeps transitions with small errors from starving.

* SALE, state-action learned embeddings: an encoder learns ``z_s = f(s)`` and
  ``z_sa = g(z_s, a)`` by regressing ``g(f(s), a)`` on ``f(s')`` (a stopped target, so the
  embedding cannot collapse the loss by moving its own target); actor and critics read the
  embeddings beside their raw inputs (``rl_jax.training.networks.StateActionEncoder``).

* Value clipping: the bootstrap value ``min_i q_t[i]`` is clipped to the range of targets seen
  up to the last target update, which stops a critic's extrapolation to unseen actions from
  feeding on itself (TD7 clips this way alongside LAP, whose linear loss tolerates outliers).
* Policy checkpoints: the policy used for evaluation is not the latest actor but a checkpoint,
  replaced only when an *assessment* of the acting actor (held fixed for it) over a number of
  training episodes has a lowest return at least the checkpoint's score; one episode below the
  score ends an assessment early (``rl_jax.training.policy_checkpoints``, shared with DQN).

Naming as rlax (and ``td3``): ``td_tm1`` is the TD error of the transition's start state,
``[num_critics, B]``.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol, cast

import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax.training import policy_checkpoints, prioritized
from rl_jax.training.networks import Params, StateActionEncoder
from rl_jax.training.offpolicy import OffPolicyConfig
from rl_jax.training.params import Scalar
from rl_jax.training.prioritized import PrioritizedBuffer
from rl_jax.training.replay import Transition

#: LAP's floor on priorities, which is also where its loss turns from quadratic to linear.
LAP_MIN_PRIORITY = 1.0


def lap_huber(td_tm1: jax.Array, threshold: float = LAP_MIN_PRIORITY) -> jax.Array:
    """Elementwise ``0.5 td^2`` where ``|td| < threshold``, else ``threshold |td|``.

    The LAP paper's Huber loss, as TD7 computes it: the linear part is not shifted down by
    ``threshold^2 / 2``, so the value jumps at the threshold while the gradient (``td`` inside,
    ``threshold sign(td)`` outside) is the ordinary Huber gradient."""
    magnitude = jnp.abs(td_tm1)
    return jnp.where(magnitude < threshold, 0.5 * td_tm1**2, threshold * magnitude)


def lap_loss(td_tm1: jax.Array) -> jax.Array:
    """The critics' LAP loss: ``lap_huber`` summed over critics and averaged over the batch
    (``td_tm1`` [num_critics, B]), as the mean squared error of plain TD3 is."""
    return jnp.sum(jnp.mean(lap_huber(td_tm1), axis=-1))


def lap_priorities(td_tm1: jax.Array) -> jax.Array:
    """``[B]`` priorities ``max(max_i |td_i|, 1)``: the largest error over the critics, floored
    at 1. The replay raises them to ``alpha`` (``prioritized.update_priorities``)."""
    return jnp.maximum(jnp.max(jnp.abs(td_tm1), axis=0), LAP_MIN_PRIORITY)


def sale_loss(zsa_tm1: jax.Array, zs_t: jax.Array) -> jax.Array:
    """SALE's encoder loss: the mean squared error of ``z_sa`` [B, D] predicting the next state's
    embedding ``z_s'`` [B, D], which is a target (no gradient)."""
    return jnp.mean((zsa_tm1 - jax.lax.stop_gradient(zs_t)) ** 2)


def value_clipped_target(
    r_t: jax.Array, discount_t: jax.Array, q_t: jax.Array, low: jax.Array, high: jax.Array
) -> jax.Array:
    """``r_t + discount_t * clip(min_i q_t[i], low, high)`` with no gradient; ``q_t`` [C, B]."""
    return jax.lax.stop_gradient(r_t + discount_t * jnp.clip(jnp.min(q_t, axis=0), low, high))


# ---- the state TD7 keeps beside its networks -----------------------------------------------------
@struct.dataclass
class Encoders:
    """SALE's encoder (``networks.StateActionEncoder`` parameters) and its fixed copies."""

    online: Params  # learns every update
    fixed: Params  # what the actor and critics read: the online one at the last target update
    fixed_target: Params  # what the targets read: the fixed one before that
    opt: optax.OptState  # Adam state of ``online``

    def renewed(self) -> Encoders:
        """At a target update: fixed target <- fixed <- online."""
        return dataclasses.replace(self, fixed_target=self.fixed, fixed=self.online)


@struct.dataclass
class ValueRange:
    """Value clipping's bounds: bootstrap values are clipped to ``[low, high]``, the extremes of
    the targets seen up to the last target update (``[0, 0]`` before the first, as TD7)."""

    low: jax.Array  # [] float32
    high: jax.Array
    seen_min: jax.Array  # [] float32, the extremes of all targets so far
    seen_max: jax.Array

    @classmethod
    def initial(cls) -> ValueRange:
        """``[0, 0]`` bounds, with extremes that any target replaces."""
        zero = jnp.float32(0.0)
        no_min = jnp.float32(policy_checkpoints.NO_EPISODE)
        no_max = jnp.float32(policy_checkpoints.NO_SCORE)
        return cls(low=zero, high=zero, seen_min=no_min, seen_max=no_max)

    def seeing(self, target_range: tuple[jax.Array, jax.Array]) -> ValueRange:
        """The extremes widened to the ``(min, max)`` of a batch's targets."""
        low, high = target_range
        return dataclasses.replace(
            self,
            seen_min=jnp.minimum(self.seen_min, low),
            seen_max=jnp.maximum(self.seen_max, high),
        )

    def renewed(self) -> ValueRange:
        """At a target update: the bounds become the extremes seen so far."""
        return dataclasses.replace(self, low=self.seen_min, high=self.seen_max)


# ---- SALE's embeddings of a fixed encoder, and LAP's replay --------------------------------------
def embed_state(encoder: StateActionEncoder, params: Params, obs: jax.Array) -> jax.Array:
    """``z_s = f(obs)`` of a fixed encoder (no gradient into its parameters)."""
    z_s = encoder.apply(jax.lax.stop_gradient(params), obs, method="embed_state")
    return cast(jax.Array, z_s)


def embeddings(
    encoder: StateActionEncoder, params: Params, obs: jax.Array, action: jax.Array
) -> jax.Array:
    """The critics' extra input ``[z_sa, z_s]`` of a fixed encoder."""
    zs = embed_state(encoder, params, obs)
    zsa = encoder.apply(jax.lax.stop_gradient(params), zs, action, method="embed_pair")
    zsa = cast(jax.Array, zsa)
    return jnp.concatenate([zsa, zs], axis=-1)


def init_buffer(example: Transition, config: OffPolicyConfig) -> PrioritizedBuffer:
    """An empty LAP replay: a prioritized buffer of ``buffer_size`` transitions."""
    return prioritized.init(example, config.buffer_size, config.num_envs)


class LapHyperparams(Protocol):
    """What LAP's replay reads of the learner's hyperparameters."""

    @property
    def lap_alpha(self) -> Scalar:
        """``P(i)`` proportional to ``max(|TD error|, 1)^lap_alpha``."""
        ...


def add_to_buffer(
    buffer: PrioritizedBuffer,
    transitions: Transition,
    config: OffPolicyConfig,
    hparams: LapHyperparams,
) -> PrioritizedBuffer:
    """Store one row at the largest priority so far."""
    return prioritized.add(buffer, transitions, hparams.lap_alpha)
