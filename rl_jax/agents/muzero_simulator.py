"""The true simulator as MuZero's model (``muzero.Config.model = "simulator"``): AlphaZero on a
single-agent functional env, as MuZero's paper frames AlphaZero (MuZero with a known model).

The search's hidden state is the env's own state: the root is each vmapped env's state as the
train env holds it under its wrappers (``EpisodeStatistics(AutoReset(eval env))``: the eval env's
state, ``StatisticsState.env_state``), and ``recurrent_fn`` steps the eval env itself (no
autoreset) from it. A transition pays the env's reward with discount ``gamma * (1 -
terminated)``; the time limit is no terminal (``truncated`` is ignored inside the search). A node
at or below a terminal state is *done*: its transitions pay 0 with discount 0 and keep the state,
and its value is 0, so a subtree past a terminal stays well-defined and adds nothing.

The env's randomness: every expansion draws its step key from the key mctx hands that
simulation (split per env), so a node's children are one sample of the env's transition, kept
for the rest of the search; the deterministic search (evaluation) uses the fixed key
``key(0)``. CartPole's step is deterministic, so the model is exact there.

The network is only MuZero's prediction ``f(obs) -> (policy, value)`` on observations (value
categorical after ``h``, as in ``muzero_parts``); its observation of a node is the env's.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import mctx

from rl_jax import envs
from rl_jax.agents import muzero_parts as parts
from rl_jax.training import networks

#: ``obs [B, ...] -> (policy logits [B, A], value logits [B, V])``
PredictFn = Callable[[jax.Array], tuple[jax.Array, jax.Array]]


class PredictionNet(nn.Module):
    """MuZero's prediction MLP on the flattened observation: policy and value logits."""

    num_actions: int
    hidden: tuple[int, ...]
    value_bins: int

    def setup(self) -> None:
        self.prediction = networks.MLP(
            networks.Layers(hidden=self.hidden), self.num_actions + self.value_bins
        )

    def predict(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(policy logits [B, A], value logits [B, V])`` of observations ``[B, ...]``."""
        out = self.prediction(obs.reshape(obs.shape[0], -1))
        return out[..., : self.num_actions], out[..., self.num_actions :]

    def initial(self, obs: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``(obs, policy logits, value logits)``: ``muzero_parts.InitialFn`` with the
        observation as its own hidden state (what the K = 0 loss reads)."""
        return (obs, *self.predict(obs))

    def __call__(self, obs: jax.Array, action: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The network once (what ``init`` traces); ``action`` is unused."""
        del action
        return self.predict(obs)


class Node(NamedTuple):
    """A search node's embedding, ``[B, ...]`` each: the env's state, its observation and
    whether a terminal state was reached on the way to it."""

    state: envs.EnvState
    obs: jax.Array
    done: jax.Array  # bool


def make_recurrent_fn(
    env: envs.Environment, predict: PredictFn, gamma: jax.Array, value_support: int
) -> Callable[..., tuple[mctx.RecurrentFnOutput, Node]]:
    """mctx's ``recurrent_fn`` that steps ``env`` (no autoreset) from the nodes' states."""

    def recurrent_fn(
        params: object, key: jax.Array, action: jax.Array, node: Node
    ) -> tuple[mctx.RecurrentFnOutput, Node]:
        del params  # bound in predict
        keys = jax.random.split(key, action.shape[0])
        state, ts = jax.vmap(env.step)(keys, node.state, action)
        alive = ~node.done
        reward = jnp.where(alive, ts.reward.astype(jnp.float32), 0.0)
        discount = jnp.where(alive & ~ts.terminated, gamma, 0.0).astype(jnp.float32)
        done = node.done | ts.terminated

        def keep(old: jax.Array, new: jax.Array) -> jax.Array:
            """The old leaf where the node was done already."""
            return jnp.where(jnp.reshape(node.done, (-1,) + (1,) * (new.ndim - 1)), old, new)

        child = Node(jax.tree.map(keep, node.state, state), keep(node.obs, ts.obs), done)
        logits, value_logits = predict(child.obs)
        value = jnp.where(done, 0.0, parts.logits_to_scalar(value_logits, value_support))
        output = mctx.RecurrentFnOutput(
            reward=reward, discount=discount, prior_logits=logits, value=value
        )
        return output, child

    return recurrent_fn


def search(
    predict: PredictFn,
    env: envs.Environment,
    env_state: envs.EnvState,
    obs: jax.Array,
    key: jax.Array,
    gamma: jax.Array,
    settings: tuple[int, int, int],
    gumbel_scale: float = 1.0,
) -> mctx.PolicyOutput:
    """Gumbel MuZero's search over the true env from its states ``env_state`` (``[B, ...]``,
    observed as ``obs``); ``settings`` is ``(num_simulations, max_considered_actions,
    value_support)``, ``gumbel_scale`` 0 makes the search deterministic for a key."""
    num_simulations, max_considered, value_support = settings
    logits, value_logits = predict(obs)
    done = jnp.zeros(obs.shape[:1], jnp.bool_)
    root = mctx.RootFnOutput(
        prior_logits=logits,
        value=parts.logits_to_scalar(value_logits, value_support),
        embedding=Node(env_state, obs, done),
    )
    return mctx.gumbel_muzero_policy(
        (),
        key,
        root,
        make_recurrent_fn(env, predict, gamma, value_support),
        num_simulations,
        max_num_considered_actions=min(max_considered, logits.shape[-1]),
        gumbel_scale=gumbel_scale,
    )


def episode_returns(
    act: Callable[[envs.EnvState, jax.Array], jax.Array],
    env: envs.Environment,
    key: jax.Array,
    episodes: int,
) -> jax.Array:
    """Undiscounted returns ``[episodes]`` of ``act(env_state [N, ...], obs [N, ...]) ->
    actions [N]`` in ``env``: ``episodes.episode_returns``'s loop with the env's state handed
    to the policy (the search starts from it)."""
    reset_key, step_key = jax.random.split(key)
    env_state, ts = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))
    Loop = tuple[jax.Array, envs.EnvState, jax.Array, jax.Array, jax.Array]

    def running(carry: Loop) -> jax.Array:
        time, _, _, alive, _ = carry
        return jnp.logical_and(time < env.max_episode_steps, jnp.any(alive))

    def step(carry: Loop) -> Loop:
        time, env_state, obs, alive, total = carry
        keys = jax.random.split(jax.random.fold_in(step_key, time), episodes)
        env_state, ts = jax.vmap(env.step)(keys, env_state, act(env_state, obs))
        total = total + jnp.where(alive, ts.reward, 0.0)
        alive = jnp.logical_and(alive, ~jnp.logical_or(ts.terminated, ts.truncated))
        return time + 1, env_state, ts.obs, alive, total

    alive = jnp.ones(episodes, jnp.bool_)
    carry: Loop = (jnp.int32(0), env_state, ts.obs, alive, jnp.zeros(episodes, jnp.float32))
    return jax.lax.while_loop(running, step, carry)[-1]
