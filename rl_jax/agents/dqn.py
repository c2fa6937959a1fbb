"""DQN (Mnih et al. 2015) and its usual extensions, each a setting, on the off-policy machinery.

A Q-network with one output per action learns from replay with a Huber loss against a target
network; the target network takes a step ``tau`` towards the online one every
``target_update_period`` updates (``tau = 1``: the paper's periodic hard copy; ``tau < 1`` with
period 1: Polyak averaging). Exploration is epsilon-greedy, epsilon falling linearly over env
steps. Settings: ``double`` (van Hasselt et al. 2016: the online network picks the bootstrap
action, the target network values it), ``dueling`` (Wang et al. 2016), ``n_step`` returns,
``prioritized`` replay (Schaul et al. 2016, proportional: ``rl_jax.training.prioritized``),
``norm="layer"`` (LayerNorm in the Q-network, as PQN's) and ``policy_checkpoints`` (TD7's: the
greedy policy evaluated, saved and loaded is a copy of the Q-network that passed an assessment
over training episodes, ``rl_jax.training.policy_checkpoints``; CartPole's recipe uses it).

Episode ends follow the env contract, as in TD3: an n-step window stops at the first step that
ended an episode and bootstraps from that step's true next observation unless the step
*terminated* (a time-limit truncation still bootstraps). Continuous envs run through
``envs.DiscretizeActions`` with ``action_bins`` values per dimension (3 bins: the rocket's thrust
in {-1, 0, +1}).

Beside this module: its settings (``dqn_config``: ``Config``, ``PixelConfig`` for envs seen as
frames, ``Hyperparams``), its replay (``dqn_replay``), its recipes per env (``dqn_recipes``) and
its pure maths (``q_learning``). Usage is TD3's::

    config = dqn.default_config("rl_jax/CartPole-v1", double=True, n_step=3)
    hparams = dqn.default_hyperparams("rl_jax/CartPole-v1")
    state = dqn.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(dqn.train_chunk, static_argnums=1)(state, config, hparams)
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, cast

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.typing import ArrayLike

from rl_jax import envs
from rl_jax.agents.common import injected_step, linearly_decayed, polyak_update
from rl_jax.agents.dqn_config import PIXEL_ENVS, Config, Hyperparams, PixelConfig
from rl_jax.agents.dqn_recipes import RECIPES
from rl_jax.agents.dqn_replay import Buffer, add_to_buffer, init_buffer, replay_for
from rl_jax.agents.q_learning import (
    double_q_values,
    greedy_values,
    linear_schedule,
    masked_argmax,
    masked_double_q_values,
    masked_epsilon_greedy,
    masked_max,
    n_step_target,
    q_learning_loss,
)
from rl_jax.training import augment, episodes, networks, offpolicy, policy_checkpoints, validation
from rl_jax.training.offpolicy import Clock, TrainState
from rl_jax.training.policy_checkpoints import PolicyCheckpoint
from rl_jax.training.replay import NStepBatch, Transition


@struct.dataclass
class Agent:
    online: optax.Params  # Q-network parameters
    target: optax.Params  # target Q-network parameters
    opt_state: optax.InjectStatefulHyperparamsState  # holds the learning rate and clip norm
    # policy_checkpoints: the checkpoint of Q-network parameters (None without: the state and
    # checkpoints of runs without it stay as they were)
    checkpoint: PolicyCheckpoint | None = None


@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> networks.QNetwork:
    """The Q-network for ``config`` (cached: called at every trace)."""
    space = episodes.make_eval_env(config).action_space()
    if not isinstance(space, envs.Discrete):
        raise TypeError(f"DQN needs a discrete action space, got {space}")
    pixels = isinstance(config, PixelConfig)
    return networks.QNetwork(
        config.hidden,
        space.n,
        config.dueling,
        config.network_init,
        conv_layers=config.conv_layers if pixels else (),
        conv_rows=config.conv_rows() if pixels else (),
        norm=config.norm,
    )


# ---- losses on networks, one update ------------------------------------------------------------
def loss_fn(
    online: optax.Params,
    target: optax.Params,
    batch: NStepBatch,
    weights: jax.Array,
    hparams: Hyperparams,
    config: Config,
) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """``(loss, (td_error [B], q_taken mean))``; the target net enters only through the
    stopped-gradient target."""
    net = make_network(config)
    q_tm1 = net.apply(online, batch.obs)
    q_t = cast(jax.Array, net.apply(target, batch.next_obs))
    legal_t = batch.next_legal  # for an env with an action mask: bootstrap over legal actions
    if config.double and legal_t is not None:
        q_t_online = cast(jax.Array, net.apply(online, batch.next_obs))
        v_t = masked_double_q_values(q_t, q_t_online, legal_t)
    elif config.double:
        v_t = double_q_values(q_t, net.apply(online, batch.next_obs))
    elif legal_t is not None:
        v_t = masked_max(q_t, legal_t)
    else:
        v_t = greedy_values(q_t)
    target_tm1 = n_step_target(batch.r_t, batch.discount_t, v_t)
    loss, td_error = q_learning_loss(q_tm1, batch.action, target_tm1, weights, hparams.huber_delta)
    return loss, (td_error, jnp.mean(target_tm1 - td_error))  # the mean q of the taken actions


def _optimizer(learning_rate: ArrayLike, max_grad_norm: ArrayLike) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), optax.adam(learning_rate))


def learning_rate_at(env_steps: jax.Array, hparams: Hyperparams) -> jax.Array:
    """The Adam rate after ``env_steps``: linear decay to 0 over ``lr_decay_steps`` (if > 0).
    DQN's greedy policy on CartPole otherwise keeps collapsing and recovering long after it first
    scores 500."""
    return linearly_decayed(hparams.learning_rate, env_steps, hparams.lr_decay_steps)


def _gradient_step(
    agent: Agent, grads: optax.Updates, hparams: Hyperparams, env_steps: jax.Array
) -> Agent:
    online, opt_state = injected_step(
        _optimizer,
        grads,
        agent.opt_state,
        agent.online,
        learning_rate=learning_rate_at(env_steps, hparams),
        max_grad_norm=hparams.max_grad_norm,
    )
    return agent.replace(online=online, opt_state=opt_state)


def _shifted(batch: NStepBatch, key: jax.Array, shift: int) -> NStepBatch:
    """DrQ's random shifts (``PixelConfig.augment_shift``): obs and next_obs apart."""
    obs_key, next_key = jax.random.split(jax.random.fold_in(key, 1))
    return batch._replace(
        obs=augment.random_shift(obs_key, batch.obs, shift),
        next_obs=augment.random_shift(next_key, batch.next_obs, shift),
    )


def update(
    agent: Agent,
    buffer: Buffer,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
) -> tuple[Agent, Buffer, dict[str, jax.Array]]:
    """One gradient update, then (when due) a target step and new priorities."""
    replay = replay_for(config)
    batch, weights, indices = replay.sample(buffer, key, hparams, update_index)
    if isinstance(config, PixelConfig) and config.augment_shift:
        batch = _shifted(batch, key, config.augment_shift)
    (loss, (td_error, q)), grads = jax.value_and_grad(loss_fn, has_aux=True)(
        agent.online, agent.target, batch, weights, hparams, config
    )
    env_steps = offpolicy.env_steps_at_update(update_index, config)
    agent = _gradient_step(agent, grads, hparams, env_steps)
    due = (update_index + 1) % config.target_update_period == 0
    target = jax.lax.cond(
        due, lambda: polyak_update(agent.target, agent.online, hparams.tau), lambda: agent.target
    )
    agent = agent.replace(target=target)
    buffer = replay.write_priorities(buffer, indices, td_error, hparams)
    epsilon = epsilon_at(env_steps, hparams)
    return agent, buffer, {"loss": loss, "q": q, "epsilon": epsilon}


# ---- acting -------------------------------------------------------------------------------------
def epsilon_at(env_steps: jax.Array, hparams: Hyperparams) -> jax.Array:
    return linear_schedule(
        hparams.epsilon_start, hparams.epsilon_end, env_steps, hparams.epsilon_decay_steps
    )


def greedy(
    params: optax.Params, obs: jax.Array, config: Config, legal: jax.Array | None = None
) -> jax.Array:
    """Greedy actions ``[N]`` int32 of the Q-network ``params`` (among the ``legal`` ones, bool
    ``[N, A]``, for an env with an action mask)."""
    return greedy_actions(make_network(config), params, obs, legal)


def greedy_actions(
    net: networks.QNetwork, params: optax.Params, obs: jax.Array, legal: jax.Array | None = None
) -> jax.Array:
    """Greedy actions ``[N]`` int32 of ``net`` at ``params`` (legal ones, given ``legal``)."""
    if legal is not None:
        return masked_argmax(cast(jax.Array, net.apply(params, obs)), legal)
    return jnp.argmax(net.apply(params, obs), axis=-1).astype(jnp.int32)


def act(agent: Agent, obs: jax.Array, config: Config, legal: jax.Array | None = None) -> jax.Array:
    """Greedy actions ``[N]`` int32: of the online network, or the checkpoint's (legal ones,
    given the env's mask ``legal``)."""
    return greedy(policy_params(agent, config), obs, config, legal)


def policy_params(agent: Agent, config: Config) -> optax.Params:
    """The Q-network whose greedy policy is evaluated, saved as best/ and loaded."""
    return agent.checkpoint.best if config.policy_checkpoints else agent.online


def explore(
    agent: Agent,
    obs: jax.Array,
    noise: jax.Array,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    clock: Clock,
    legal: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """``(actions, noise)``. Epsilon-greedy: a uniform action with probability epsilon(env steps),
    else greedy (with ``policy_checkpoints``, the assessed copy's); both among the ``legal``
    actions (bool ``[N, A]``) for an env with an action mask. Independent from step to step,
    so the carried ``noise`` state is passed through."""
    net = make_network(config)
    acting = agent.checkpoint.assessed if config.policy_checkpoints else agent.online
    if legal is not None:
        epsilon = epsilon_at(clock.env_steps, hparams)
        q = cast(jax.Array, net.apply(acting, obs))
        return masked_epsilon_greedy(key, q, legal, epsilon), noise
    exploit = greedy_actions(net, acting, obs)
    coin_key, action_key = jax.random.split(key)
    uniform = jax.random.randint(action_key, exploit.shape, 0, net.num_actions, jnp.int32)
    explore_now = jax.random.uniform(coin_key, exploit.shape) < epsilon_at(clock.env_steps, hparams)
    return jnp.where(explore_now, uniform, exploit), noise


def observe(
    agent: Agent,
    transitions: Transition,
    episode_return: jax.Array,
    done: jax.Array,
    clock: Clock,
    config: Config,
    hparams: Hyperparams,
) -> Agent:
    """Every env step: policy checkpoints count the episodes that ended."""
    if not config.policy_checkpoints:
        return agent
    checkpoint = policy_checkpoints.assess(
        agent.checkpoint,
        agent.online,
        episode_return,
        done,
        clock,
        config,
        hparams.checkpoint_reset_weight,
    )
    return agent.replace(checkpoint=checkpoint)


# ---- init and the loop's learner ----------------------------------------------------------------
def init_agent(
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
    obs_space: envs.Space,
    action_space: envs.Space,
) -> Agent:
    online = make_network(config).init(key, jnp.zeros(obs_space.shape, jnp.float32))
    optimizer = optax.inject_hyperparams(_optimizer)(hparams.learning_rate, hparams.max_grad_norm)
    opt_state = optimizer.init(online)
    agent = Agent(online=online, target=online, opt_state=opt_state)
    if config.policy_checkpoints:
        checkpoint = policy_checkpoints.init(online, config.num_envs, config.learning_starts)
        agent = agent.replace(checkpoint=checkpoint)
    return agent


LEARNER = offpolicy.Learner(
    init_agent,
    explore,
    act,
    update,
    ("loss", "q", "epsilon"),
    init_buffer,
    add_to_buffer,
    observe,
)


# ---- the Algorithm object -----------------------------------------------------------------------
class DQN(offpolicy.OffPolicyAlgorithm[Config]):
    """DQN as an ``rl_jax.training.algorithm.Algorithm``."""

    name = "dqn"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    learner = LEARNER
    # Gradients are always clipped here: a norm of 0 would zero them (REINFORCE's 0 means off).
    ranges = {"max_grad_norm": validation.POSITIVE}

    def default_config(self, env_id: str, recipe: str | None = None, **overrides: Any) -> Config:
        """The recipe's ``Config``; a ``PixelConfig`` for the envs of ``PIXEL_ENVS``."""
        if env_id not in PIXEL_ENVS:
            return super().default_config(env_id, recipe, **overrides)
        values = {**self.recipe(env_id, recipe).config, **overrides}
        return PixelConfig(env_id=env_id, **values)

    def policy(self, state: TrainState, config: Config) -> Callable[..., jax.Array]:
        """``obs -> action index`` of the greedy policy of one seed's state (with
        ``policy_checkpoints``, the checkpoint's); for an env with an action mask
        ``(obs, legal) -> action index``, the best legal action."""
        params = policy_params(state.agent, config)
        return lambda obs, legal=None: greedy(params, obs, config, legal)

    def make_env(self, config: Config) -> envs.Environment:
        """The env the policy acts in (discretised actions), for rendering."""
        return episodes.make_eval_env(config)

    def loop_seeds(self, config: Config) -> bool:
        """Seeds as an unrolled loop where a ``PixelConfig`` asks for it (conv nets on CPU)."""
        return isinstance(config, PixelConfig) and config.loop_seeds


dqn = DQN()
default_config, default_hyperparams = dqn.default_config, dqn.default_hyperparams
init, train_chunk = dqn.init, dqn.train_chunk
