"""PPO's actor-critic network, its outputs on (standardised) observations, sampling and the
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
"""

from __future__ import annotations

import functools
from typing import cast

import flax.linen as nn
import jax
import jax.numpy as jnp

from rl_jax import envs
from rl_jax.agents.policy_gradient import masked_logits
from rl_jax.agents.ppo_config import Config, PixelConfig
from rl_jax.training import conv, episodes, networks, normalization
from rl_jax.training.networks import Params
from rl_jax.training.normalization import RunningStats

HIDDEN_GAIN = 2.0**0.5
POLICY_GAIN = 0.01
VALUE_GAIN = 1.0


def _layer(features: int, gain: float) -> nn.Dense:
    return nn.Dense(
        features,
        kernel_init=nn.initializers.orthogonal(gain),
        bias_init=nn.initializers.zeros,
    )


class _Torso(nn.Module):
    """Hidden layers, each orthogonal at gain sqrt(2) and then the nonlinearity."""

    hidden: tuple[int, ...]
    activation: str

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        function = networks.ACTIVATIONS[self.activation][0]
        for width in self.hidden:
            x = function(_layer(width, HIDDEN_GAIN)(x))
        return x


class ActorCritic(nn.Module):
    """``obs -> {"logits" | "mean", "std"; "value"}``; ``value(obs)`` runs the critic alone."""

    hidden: tuple[int, ...]
    action_dim: int = 1
    num_actions: int | None = None  # set: categorical
    activation: str = "tanh"
    initial_std: float = 1.0
    conv_layers: tuple[int, ...] = ()  # set: obs are frames [..., H, W, C], torso shared
    conv_rows: tuple[int, ...] = ()  # (first, stop): the frame rows the conv torso sees

    def setup(self) -> None:
        outputs = self.num_actions if self.num_actions is not None else self.action_dim
        self.actor_torso = _Torso(self.hidden, self.activation)
        if self.conv_layers:
            self.conv = conv.ConvTorso(self.conv_layers, "orthogonal", rows=self.conv_rows)
        else:
            self.critic_torso = _Torso(self.hidden, self.activation)
        self.policy_head = _layer(outputs, POLICY_GAIN)
        self.value_head = _layer(1, VALUE_GAIN)
        if self.num_actions is None:
            start = jnp.log(jnp.float32(self.initial_std))
            self.log_std = self.param(
                "log_std", lambda _, shape: jnp.full(shape, start), (self.action_dim,)
            )

    def _features(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        if self.conv_layers:
            shared = self.actor_torso(self.conv(obs))
            return shared, shared
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
        if self.conv_layers:
            return self.value_head(self.actor_torso(self.conv(obs)))[..., 0]
        return self.value_head(self.critic_torso(obs))[..., 0]


@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> ActorCritic:
    """The network for ``config`` (cached: called at every trace)."""
    space = episodes.make_eval_env(config).action_space()
    discrete = isinstance(space, envs.Discrete)
    conv_layers = config.conv_layers if isinstance(config, PixelConfig) else ()
    return ActorCritic(
        hidden=config.hidden,
        action_dim=1 if discrete else space.shape[0],
        num_actions=space.n if discrete else None,
        activation=config.activation,
        initial_std=config.initial_std,
        conv_layers=conv_layers,
        conv_rows=config.conv_rows() if conv_layers else (),
    )


def outputs(
    params: Params,
    obs_stats: RunningStats | None,
    obs: jax.Array,
    config: Config,
    legal: jax.Array | None = None,
) -> dict[str, jax.Array]:
    """The network on observations standardised by ``obs_stats`` (``None``: as they are). With
    ``legal`` (bool ``[..., A]``, the env's action mask) the categorical policy is the softmax
    over the legal actions only (``masked_logits``): every draw, log-probability, entropy and
    most likely action of it is then legal."""
    net = make_network(config)
    policy = cast(dict[str, jax.Array], net.apply(params, normalization.normalize(obs_stats, obs)))
    if legal is None:
        return policy
    return {**policy, "logits": masked_logits(policy["logits"], legal)}


def value(
    params: Params, obs_stats: RunningStats | None, obs: jax.Array, config: Config
) -> jax.Array:
    """The critic alone on (standardised) observations: ``[...]``."""
    net = make_network(config)
    return net.apply(params, normalization.normalize(obs_stats, obs), method=ActorCritic.value)


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
