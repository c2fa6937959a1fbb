"""PPO's parts, free of its settings: its maths and its actor-critic network.

The maths (Schulman et al. 2017), pure and network-free: generalized advantage estimates
(Schulman et al. 2016), the clipped surrogate objective, the (optionally clipped) value loss,
advantage standardisation and the running scale of rewards.

Names follow the time steps, as rlax does: a rollout step acts in ``s_tm1`` (value ``v_tm1``),
earns ``r_t`` and lands in ``s_t`` (value ``v_t``, the *true* next observation, also where the
episode was cut by the time limit). Arrays are ``[T, N]`` (time, envs) unless said otherwise.

The network: PPO's actor-critic, its outputs on (standardised) observations, sampling and the
deterministic action.

Vector observations: actor and critic are separate MLPs (no features shared, so the value loss
does not shape the policy's). Frames: one conv torso and hidden layers shared by both, each then a
linear head. Orthogonal initialisation with zero biases, the hidden layers at gain sqrt(2), the
policy head at 0.01 (a near-uniform, near-zero-mean first policy) and the value head at 1, as in
the PPO implementation studies (Engstrom et al. 2020; Andrychowicz et al. 2021).

Actions: a categorical policy for ``Discrete`` spaces; for ``Box`` spaces a diagonal Gaussian
whose log-std is one learned parameter per action dimension, independent of the state. The
Gaussian samples unbounded actions; the env step gets them clipped to the bounds, while the
log-probability (and so the ratio) is that of the unclipped sample. For an env with a
legal-action mask the categorical is over the legal actions alone (``outputs(..., legal)``).

``rl_jax.agents.ppo`` builds the network from its ``Config`` (``make_network``) and hands it
to these functions; this module does not import it.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar, Protocol, TypeVar, cast

import flax.linen as nn
import jax
import jax.numpy as jnp

from rl_jax import envs
from rl_jax.agents.policy_gradient import masked_logits
from rl_jax.training import conv, networks, normalization
from rl_jax.training.networks import Params
from rl_jax.training.normalization import RunningStats


# ---- the maths: advantages, losses, reward scale ------------------------------------------------
def generalized_advantage_estimates(
    r_t: jax.Array, discount_t: jax.Array, v_tm1: jax.Array, v_t: jax.Array, trace_t: jax.Array
) -> jax.Array:
    """``A_tm1 = delta_t + trace_t A_t`` backwards over axis 0, with the TD error
    ``delta_t = r_t + discount_t v_t - v_tm1``: ``[T, N] -> [T, N]``.

    ``discount_t`` is ``gamma`` except at a termination (0: no value after a terminal state), so a
    step cut by the time limit still bootstraps from ``v_t``, the value of its true final
    observation. ``trace_t`` is ``gamma * lambda`` except where the episode ended in any way (0: the
    next step's advantage belongs to a new episode). The last step's trace is cut too: no
    advantage is known beyond the rollout, and ``v_t`` already bootstraps for it."""
    delta_t = r_t + discount_t * v_t - v_tm1

    def back(a_next: jax.Array, inputs: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        delta, trace = inputs
        a = delta + trace * a_next
        return a, a

    _, advantages = jax.lax.scan(back, jnp.zeros_like(delta_t[0]), (delta_t, trace_t), reverse=True)
    return advantages


def normalize_advantages(adv_t: jax.Array, eps: float = 1e-8) -> jax.Array:
    """``(adv - mean) / (std + eps)`` over the whole (mini)batch (population std)."""
    return (adv_t - jnp.mean(adv_t)) / (jnp.std(adv_t) + eps)


def clipped_surrogate_loss(
    log_pi_t: jax.Array, log_mu_t: jax.Array, adv_t: jax.Array, epsilon: float | jax.Array
) -> jax.Array:
    """The negated clipped surrogate objective (PPO's L^CLIP), averaged:
    ``mean(max(-A rho, -A clip(rho, 1 - eps, 1 + eps)))`` with ``rho = pi / mu`` the ratio of the
    current policy's probability of the taken action to the behaviour policy's. The advantages
    are constants here; only ``log_pi_t`` carries a gradient."""
    rho_t = jnp.exp(log_pi_t - jax.lax.stop_gradient(log_mu_t))
    adv_t = jax.lax.stop_gradient(adv_t)
    unclipped = -adv_t * rho_t
    clipped = -adv_t * jnp.clip(rho_t, 1.0 - epsilon, 1.0 + epsilon)
    return jnp.mean(jnp.maximum(unclipped, clipped))


def value_loss(v_t: jax.Array, target_t: jax.Array) -> jax.Array:
    """``0.5 mean((v - target)^2)``."""
    return 0.5 * jnp.mean((v_t - jax.lax.stop_gradient(target_t)) ** 2)


def clipped_value_loss(
    v_t: jax.Array, v_old_t: jax.Array, target_t: jax.Array, epsilon: float | jax.Array
) -> jax.Array:
    """``0.5 mean(max((v - target)^2, (v_clip - target)^2))`` with ``v_clip`` the new value kept
    within ``epsilon`` of the value at collection (``v_old_t``): the pessimistic of the two, so
    a step cannot gain by moving the value further than ``epsilon``."""
    target_t = jax.lax.stop_gradient(target_t)
    v_old_t = jax.lax.stop_gradient(v_old_t)
    v_clipped = v_old_t + jnp.clip(v_t - v_old_t, -epsilon, epsilon)
    return 0.5 * jnp.mean(jnp.maximum((v_t - target_t) ** 2, (v_clipped - target_t) ** 2))


def policy_statistics(
    log_pi_t: jax.Array, log_mu_t: jax.Array, epsilon: float | jax.Array
) -> dict[str, jax.Array]:
    """Diagnostics of one minibatch: ``approx_kl``, the estimate ``mean((rho - 1) - log rho)``
    of KL(mu || pi) (non-negative, unbiased), and ``clip_fraction``, the share of ratios outside
    ``[1 - eps, 1 + eps]``."""
    log_rho = jax.lax.stop_gradient(log_pi_t - log_mu_t)
    rho = jnp.exp(log_rho)
    return {
        "approx_kl": jnp.mean((rho - 1.0) - log_rho),
        "clip_fraction": jnp.mean((jnp.abs(rho - 1.0) > epsilon).astype(jnp.float32)),
    }


def discounted_returns(
    r_t: jax.Array, ended_t: jax.Array, g_0: jax.Array, gamma: float | jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The running discounted return of each env's current episode, ``g_t = gamma g_tm1 + r_t``,
    restarted after an episode ends (``ended_t``: terminated or truncated at step t).
    ``g_0 [N]`` is the value carried in from the previous rollout (already restarted where the
    previous step ended an episode). Returns ``(g [T, N], the carry for the next rollout [N])``."""

    def forward(
        g_prev: jax.Array, inputs: tuple[jax.Array, jax.Array]
    ) -> tuple[jax.Array, jax.Array]:
        r, ended = inputs
        g = gamma * g_prev + r
        return jnp.where(ended, 0.0, g), g

    carry, g_t = jax.lax.scan(forward, g_0, (r_t, ended_t))
    return g_t, carry


def scale_rewards(
    r_t: jax.Array, g_t: jax.Array, stats: normalization.RunningStats, clip: float | jax.Array
) -> tuple[jax.Array, normalization.RunningStats]:
    """Rewards divided by the running std of the discounted returns ``g_t`` (after folding them
    into ``stats``), then clipped to ``+-clip`` (``clip <= 0``: not clipped). The scale keeps the
    value targets near unit size whatever the env's reward units; the mean is not removed, so the
    sign of every reward stays. Returns ``(scaled r_t, new stats)``."""
    stats = normalization.update(stats, g_t[..., None], jnp.ones_like(g_t))
    scaled = r_t / jnp.sqrt(stats.var[0] + normalization.EPSILON)
    scaled = jnp.where(clip > 0.0, jnp.clip(scaled, -clip, clip), scaled)
    return scaled, stats


class ScalesRewards(Protocol):
    """A learner state (a dataclass) that can keep the running reward scale: the statistics of
    the discounted returns and each env's running return, both ``None`` without
    ``normalize_rewards``."""

    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[object]]]

    @property
    def return_stats(self) -> normalization.RunningStats | None: ...

    @property
    def discounted_return(self) -> jax.Array | None: ...


StateT = TypeVar("StateT", bound=ScalesRewards)


def with_reward_scale(state: StateT, num_envs: int) -> StateT:
    """``state`` with a fresh reward scale for ``num_envs`` envs (``normalize_rewards``)."""
    zeros = jnp.zeros(num_envs, jnp.float32)
    return dataclasses.replace(state, return_stats=normalization.init(1), discounted_return=zeros)


def lambda_targets(
    state: StateT,
    r_t: jax.Array,
    terminated_t: jax.Array,
    truncated_t: jax.Array,
    v_tm1: jax.Array,
    v_t: jax.Array,
    gamma: float | jax.Array,
    gae_lambda: float | jax.Array,
    reward_clip: float | jax.Array,
    normalize: bool,
) -> tuple[jax.Array, jax.Array, StateT]:
    """``(advantages [T, N], lambda-returns [T, N], state)`` of one rollout: generalized
    advantage estimates on the rewards, scaled first with ``normalize`` (``scale_rewards``, by
    the scale that ``state`` keeps; the returned state then holds it updated by this rollout).
    Bootstraps through truncations (``v_t`` is the true next observation's value), not through
    terminations; the traces stop at both."""
    ended = jnp.logical_or(terminated_t, truncated_t)
    if normalize:
        assert state.return_stats is not None and state.discounted_return is not None
        g_t, carry = discounted_returns(r_t, ended, state.discounted_return, gamma)
        r_t, stats = scale_rewards(r_t, g_t, state.return_stats, reward_clip)
        state = dataclasses.replace(state, return_stats=stats, discounted_return=carry)
    discount_t = gamma * (1.0 - terminated_t.astype(jnp.float32))
    trace_t = gamma * gae_lambda * (1.0 - ended.astype(jnp.float32))
    advantage = generalized_advantage_estimates(r_t, discount_t, v_tm1, v_t, trace_t)
    return advantage, advantage + v_tm1, state


# ---- the actor-critic network -------------------------------------------------------------------
HIDDEN_GAIN = 2.0**0.5
POLICY_GAIN = 0.01
VALUE_GAIN = 1.0


def _layer(features: int, gain: float) -> nn.Dense:
    return nn.Dense(
        features,
        kernel_init=nn.initializers.orthogonal(gain),
        bias_init=nn.initializers.zeros,
    )


def check_orthogonal_layers(layers: networks.Layers, owner: str) -> None:
    """``ValueError`` unless ``layers`` are what PPO's networks build: orthogonal float32 layers
    without norm (only ``hidden`` and ``activation`` may vary)."""
    plain = networks.Layers(layers.hidden, activation=layers.activation, initializer="orthogonal")
    if layers != plain:
        raise ValueError(
            f"{owner}'s layers are orthogonal float32 MLP layers without norm (only hidden and "
            f"activation vary), got {layers}"
        )


class _Torso(nn.Module):
    """Hidden layers, each orthogonal at gain sqrt(2) and then the nonlinearity."""

    layers: networks.Layers

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        function = networks.ACTIVATIONS[self.layers.activation][0]
        for width in self.layers.hidden:
            x = function(_layer(width, HIDDEN_GAIN)(x))
        return x


class ActorCritic(nn.Module):
    """``obs -> {"logits" | "mean", "std"; "value"}``; ``value(obs)`` runs the critic alone.
    ``layers``: the hidden layers of each torso (see ``check_orthogonal_layers``)."""

    layers: networks.Layers
    action_dim: int = 1
    num_actions: int | None = None  # set: categorical
    initial_std: float = 1.0
    conv_layers: tuple[int, ...] = ()  # set: obs are frames [..., H, W, C], torso shared
    conv_rows: tuple[int, ...] = ()  # (first, stop): the frame rows the conv torso sees
    obs_high: float = 255.0  # images' largest value, scaled to 1 by the conv torso
    # without conv layers: image observations [..., H, W, C] flattened before the MLPs
    flatten_image: bool = False

    def setup(self) -> None:
        """Builds the torsos (one conv torso shared on frames), the heads and, for a
        Gaussian, the learned log-std."""
        check_orthogonal_layers(self.layers, "ActorCritic")
        outputs = self.num_actions if self.num_actions is not None else self.action_dim
        self.actor_torso = _Torso(layers=self.layers)
        if self.conv_layers:
            self.conv = conv.ConvTorso(
                self.conv_layers, "orthogonal", rows=self.conv_rows, high=self.obs_high
            )
        else:
            self.critic_torso = _Torso(layers=self.layers)
        self.policy_head = _layer(outputs, POLICY_GAIN)
        self.value_head = _layer(1, VALUE_GAIN)
        if self.num_actions is None:
            start = jnp.log(jnp.float32(self.initial_std))
            self.log_std = self.param(
                "log_std", lambda _, shape: jnp.full(shape, start), (self.action_dim,)
            )

    def _flat(self, obs: jax.Array) -> jax.Array:
        return obs.reshape(obs.shape[:-3] + (-1,)) if self.flatten_image else obs

    def _features(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        if self.conv_layers:
            shared = self.actor_torso(self.conv(obs))
            return shared, shared
        obs = self._flat(obs)
        return self.actor_torso(obs), self.critic_torso(obs)

    def __call__(self, obs: jax.Array) -> dict[str, jax.Array]:
        actor, critic = self._features(obs)
        out = {"value": self.value_head(critic)[..., 0]}
        if self.num_actions is not None:
            return {**out, "logits": self.policy_head(actor)}
        mean = self.policy_head(actor)
        std = jnp.broadcast_to(jnp.exp(self.log_std), mean.shape)
        return {**out, "mean": mean, "std": std}

    def value(self, obs: jax.Array) -> jax.Array:
        """The critic's values ``[...]`` of ``obs``."""
        if self.conv_layers:
            return self.value_head(self.actor_torso(self.conv(obs)))[..., 0]
        return self.value_head(self.critic_torso(self._flat(obs)))[..., 0]


def outputs(
    net: ActorCritic,
    params: Params,
    obs_stats: RunningStats | None,
    obs: jax.Array,
    legal: jax.Array | None = None,
) -> dict[str, jax.Array]:
    """The network on observations standardised by ``obs_stats`` (``None``: as they are). With
    ``legal`` (bool ``[..., A]``, the env's action mask) the categorical policy is the softmax
    over the legal actions only (``masked_logits``): every draw, log-probability, entropy and
    most likely action of it is then legal."""
    policy = cast(dict[str, jax.Array], net.apply(params, normalization.normalize(obs_stats, obs)))
    if legal is None:
        return policy
    return {**policy, "logits": masked_logits(policy["logits"], legal)}


def value(
    net: ActorCritic, params: Params, obs_stats: RunningStats | None, obs: jax.Array
) -> jax.Array:
    """The critic alone on (standardised) observations: ``[...]``."""
    values = net.apply(params, normalization.normalize(obs_stats, obs), method=ActorCritic.value)
    return cast(jax.Array, values)


def sample_action(policy: dict[str, jax.Array], key: jax.Array) -> jax.Array:
    """A draw from the policy (unclipped for the Gaussian)."""
    if "logits" in policy:
        return jax.random.categorical(key, policy["logits"]).astype(jnp.int32)
    return policy["mean"] + policy["std"] * jax.random.normal(key, policy["mean"].shape)


def to_env_action(action: jax.Array, space: envs.Space) -> jax.Array:
    """What the env steps with: a Gaussian draw clipped to the bounds; an index as it is."""
    if isinstance(space, envs.Box):
        leading = (1,) * (action.ndim - len(space.shape))
        low, high = (jnp.reshape(bound, leading + space.shape) for bound in (space.low, space.high))
        return jnp.clip(action, low, high)
    return action


def deterministic_action(policy: dict[str, jax.Array], space: envs.Space) -> jax.Array:
    """The most likely action (the Gaussian's mean, clipped to the bounds)."""
    if "logits" in policy:
        return jnp.argmax(policy["logits"], axis=-1).astype(jnp.int32)
    return to_env_action(policy["mean"], space)
