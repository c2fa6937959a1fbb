"""What the deterministic actor-critics (TD3 and DDPG, TD7, CrossQ) share: their common settings,
the actor and stacked critics with the action bounds, acting with exploration noise, the batch a
critic update reads, and the pure maths of their targets and losses.

Naming as rlax: ``tm1`` is a transition's start, ``t`` its end; ``q_t`` ``[num_critics, B]``.
Noise scales are fractions of the action half-range ``(high - low) / 2``, as the TD3 reference
code scales them by ``max_action``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple, TypeVar, cast

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.spaces import Box, Space
from rl_jax.training import networks, params, replay
from rl_jax.training.networks import Params
from rl_jax.training.offpolicy import OffPolicyConfig
from rl_jax.training.params import Scalar
from rl_jax.training.replay import ReplayBuffer, Transition


@dataclasses.dataclass(frozen=True, kw_only=True)
class ActorCriticConfig(OffPolicyConfig):
    """The settings every deterministic actor-critic has (the loop's are ``OffPolicyConfig``'s);
    defaults: the TD3 paper's."""

    actor_hidden: tuple[int, ...] = (256, 256)  # hidden layer widths of the actor
    critic_hidden: tuple[int, ...] = (256, 256)  # hidden layer widths of each critic
    num_critics: int = 2  # critics; the target takes the min over them (TD3 2, DDPG 1)
    policy_delay: int = 2  # critic updates per actor (and target) update; DDPG 1
    network_init: networks.Initializer = "fan_in_uniform"  # see rl_jax.training.networks
    compute_dtype: str = "float32"  # matmul dtype ("bfloat16" trades precision for speed)
    actor_activation: networks.Activation = "relu"  # the actor's nonlinearity: relu, tanh, elu
    critic_activation: networks.Activation = "relu"  # of the critics

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.num_critics < 1 or self.policy_delay < 1:
            raise ValueError("num_critics and policy_delay must be >= 1")
        if self.network_init not in networks.INITS:
            raise ValueError(f"network_init must be one of {networks.INITS}")
        for name in ("actor_activation", "critic_activation"):
            if getattr(self, name) not in networks.ACTIVATIONS:
                raise ValueError(f"{name} must be one of {tuple(networks.ACTIVATIONS)}")


@struct.dataclass
class ActorCriticHyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: the TD3 paper's (code's) values."""

    actor_lr: Scalar = 3e-4  # Adam step size of the actor
    critic_lr: Scalar = 3e-4  # Adam step size of the critics
    gamma: Scalar = 0.99  # discount
    exploration_noise: Scalar = 0.1  # std of the Gaussian added to actions, x half-range
    # Step-to-step correlation rho of that noise, n_t = rho n_{t-1} + sqrt(1 - rho^2) eps_t (an
    # AR(1), i.e. discretised Ornstein-Uhlenbeck, process with the same std). 0: independent
    # noise, as in the TD3 paper. Near 1: slow pushes, as the original DDPG's OU noise; inertial
    # systems with a small time step need them, since independent noise averages out.
    exploration_correlation: Scalar = 0.0
    target_noise: Scalar = 0.2  # std of target policy smoothing, x half-range (0 turns it off)
    target_noise_clip: Scalar = 0.5  # smoothing noise clipped to +-this, x half-range
    # Env steps (all envs) over which both learning rates fall linearly to 0 (0: constant).
    lr_decay_steps: Scalar = 0.0


#: A learning rate's schedule: the rate for this update from the hyperparameter's value.
Rate = Callable[[Scalar], jax.Array]


class Networks(NamedTuple):
    """An actor, one critic module (stacked ``num_critics`` times in the parameters) and the
    bounds the actions live in."""

    actor: networks.Actor
    critic: networks.Critic
    low: np.ndarray  # [action_dim]
    high: np.ndarray

    @property
    def half_range(self) -> np.ndarray:
        """Half the width of the action bounds, ``[action_dim]``."""
        return (self.high - self.low) / 2.0


def bounded_box(action_space: Space, learner: str) -> Box:
    """``action_space`` itself; ``TypeError`` unless a bounded 1-D ``Box``."""
    if (
        not isinstance(action_space, Box)
        or not action_space.bounded
        or len(action_space.shape) != 1
    ):
        raise TypeError(f"{learner} needs a bounded 1-D Box action space, got {action_space}")
    return action_space


def bounds(action_space: Space, learner: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The action bounds as tuples; ``TypeError`` unless a bounded 1-D ``Box``."""
    box = bounded_box(action_space, learner)
    return tuple(float(x) for x in box.low), tuple(float(x) for x in box.high)


def row(x: np.ndarray, like: jax.Array) -> jax.Array:
    """Bounds shaped to broadcast against ``like`` [..., action_dim] without rank promotion."""
    return jnp.reshape(jnp.asarray(x, jnp.float32), (1,) * (like.ndim - 1) + (-1,))


def critic_values(
    nets: Networks, critics: Params, obs: jax.Array, action: jax.Array, *extra: jax.Array
) -> jax.Array:
    """``[num_critics, B]``: every stacked critic at ``(obs, action)`` (``extra``: more inputs,
    such as TD7's embeddings)."""
    return networks.apply_stacked(nets.critic, critics, obs, action, *extra)


def first_critic_value(
    nets: Networks, critics: Params, obs: jax.Array, action: jax.Array, *extra: jax.Array
) -> jax.Array:
    """``[B]``: the first critic alone (the one the actor ascends)."""
    first = jax.tree.map(lambda x: x[0], critics)
    return cast(jax.Array, nets.critic.apply(first, obs, action, *extra))


def actor_action(nets: Networks, actor: Params, obs: jax.Array, *extra: jax.Array) -> jax.Array:
    """The deterministic action of actor parameters ``actor`` at ``obs`` (``extra``: more
    inputs, such as TD7's ``z_s``). Flax types ``apply`` as its output or a pair with updated
    state; an actor has no state to update."""
    return cast(jax.Array, nets.actor.apply(actor, obs, *extra))


def explore(
    action: jax.Array,
    noise: jax.Array,
    key: jax.Array,
    nets: Networks,
    hparams: ActorCriticHyperparams,
) -> tuple[jax.Array, jax.Array]:
    """``(actions, noise)``: ``action`` plus ``exploration_noise`` x half-range x an AR(1) noise
    of unit std (independent when ``exploration_correlation`` is 0), clipped to the bounds."""
    rho = hparams.exploration_correlation
    noise = rho * noise + jnp.sqrt(1.0 - rho**2) * jax.random.normal(key, action.shape)
    scaled = hparams.exploration_noise * row(nets.half_range, action) * noise
    return jnp.clip(action + scaled, row(nets.low, action), row(nets.high, action)), noise


# ---- the batch a critic update reads -----------------------------------------------------------
class CriticBatch(NamedTuple):
    """The target is ``r_t + discount_t * min_i q_t[i]`` at ``next_obs`` (one step: ``gamma`` or
    0 at termination; n steps: the folded window)."""

    obs: jax.Array
    action: jax.Array
    r_t: jax.Array  # [B]
    discount_t: jax.Array  # [B]
    next_obs: jax.Array

    @classmethod
    def one_step(cls, batch: Transition, gamma: Scalar) -> CriticBatch:
        """From one-step transitions: ``discount_t`` is ``gamma``, 0 where terminated."""
        discount_t = gamma * (1.0 - batch.terminated.astype(jnp.float32))
        return cls(batch.obs, batch.action, batch.reward, discount_t, batch.next_obs)

    @classmethod
    def n_step(cls, batch: replay.NStepBatch) -> CriticBatch:
        """From an n-step window: its rewards and discounts folded into one return."""
        r_t, discount_t = replay.fold_n_step(batch.r_t, batch.discount_t)
        return cls(batch.obs, batch.action, r_t, discount_t, batch.next_obs)


def gather_batch(
    storage: ReplayBuffer[Transition],
    rows: jax.Array,
    columns: jax.Array,
    gamma: Scalar,
    n_step: int = 1,
) -> CriticBatch:
    """The ``CriticBatch`` of stored transitions ``(rows, columns)``: one step each, or windows
    of ``n_step`` consecutive steps of one env (cut at an episode's end)."""
    if n_step == 1:
        return CriticBatch.one_step(replay.gather(storage, rows, columns), gamma)
    window, stored = replay.gather_windows(storage, rows, columns, n_step)
    return CriticBatch.n_step(replay.n_step_batch(window, stored, gamma))


# ---- loss maths (pure) -------------------------------------------------------------------------
AgentT = TypeVar("AgentT")
Outputs = TypeVar("Outputs")


def every_policy_delay(
    update_index: jax.Array,
    policy_delay: int,
    step: Callable[[AgentT], tuple[AgentT, Outputs]],
    agent: AgentT,
) -> tuple[AgentT, Outputs]:
    """``step(agent)`` at every ``policy_delay``-th update (``update_index`` counts the updates
    before this one), the delayed actor update of TD3 and its kin; otherwise ``agent`` as it is,
    with NaN for each of ``step``'s outputs (metrics of an update not made)."""
    skipped = jax.tree.map(
        lambda out: jnp.full(out.shape, jnp.nan, out.dtype), jax.eval_shape(step, agent)[1]
    )
    delayed = (update_index + 1) % policy_delay == 0
    return jax.lax.cond(delayed, step, lambda agent: (agent, skipped), agent)


def smoothed_target_action(
    a_t: jax.Array, noise: jax.Array, noise_clip: jax.Array, low: jax.Array, high: jax.Array
) -> jax.Array:
    """Target policy smoothing: ``clip(a_t + clip(noise, -noise_clip, noise_clip), low, high)``."""
    return jnp.clip(a_t + jnp.clip(noise, -noise_clip, noise_clip), low, high)


def target_action(
    a_t: jax.Array, noise: jax.Array, hparams: ActorCriticHyperparams, nets: Networks
) -> jax.Array:
    """``a_t`` plus smoothing noise ``target_noise * noise`` clipped to ``+-target_noise_clip``
    (both x the action half-range); ``noise`` is standard normal."""
    scale = row(nets.half_range, a_t)
    return smoothed_target_action(
        a_t,
        hparams.target_noise * scale * noise,
        hparams.target_noise_clip * scale,
        row(nets.low, a_t),
        row(nets.high, a_t),
    )


def clipped_double_q_target(r_t: jax.Array, discount_t: jax.Array, q_t: jax.Array) -> jax.Array:
    """``r_t + discount_t * min_i q_t[i]`` with no gradient; ``q_t`` [num_critics, B] -> [B].
    With one critic this is the plain DDPG target. ``discount_t`` is 0 at termination."""
    return jax.lax.stop_gradient(r_t + discount_t * jnp.min(q_t, axis=0))


def critic_loss(
    q_tm1: jax.Array, r_t: jax.Array, discount_t: jax.Array, q_t: jax.Array
) -> jax.Array:
    """Sum over critics of the mean squared error to the shared target; ``q_tm1`` [C, B]."""
    target = clipped_double_q_target(r_t, discount_t, q_t)
    return jnp.sum(jnp.mean((q_tm1 - target[None, :]) ** 2, axis=-1))


def deterministic_policy_loss(q_tm1: jax.Array) -> jax.Array:
    """The actor ascends Q at its own action: loss ``-mean(q_tm1)``."""
    return -jnp.mean(q_tm1)
