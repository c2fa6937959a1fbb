"""Expected SARSA for discrete actions: a learner written outside rl_jax, on its interface.

Every env of a seed takes an epsilon-greedy step; one gradient step then moves Q(s, a) towards
r + gamma * E[Q'(s', a')] over the epsilon-greedy policy's actions in s' (Q' follows Q slowly).
No replay buffer: the envs stepped together batch each update. Guide: docs/own_learner.md.

    python experiments/train.py --algo examples/expected_sarsa.py:learner --env rl_jax/CartPole-v1
"""

import dataclasses
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from rl_jax import envs
from rl_jax.training import episodes
from rl_jax.training.algorithm import ChunkMetrics
from rl_jax.training.params import HyperparamsMethods


@dataclasses.dataclass(frozen=True)
class Config:  # static: shapes and loop lengths; a change compiles another program
    env_id: str = "rl_jax/CartPole-v1"
    num_envs: int = 16  # envs of one seed, stepped together
    iterations_per_chunk: int = 250  # steps of every env between two evaluations
    hidden: tuple[int, ...] = (64, 64)  # widths of the Q-network's hidden layers
    num_eval_envs: int = 10  # episodes of each evaluation

    def make_env(self) -> envs.Environment:  # what rl_jax.training.episodes builds envs from
        return envs.make(self.env_id)


@struct.dataclass
class Hyperparams(HyperparamsMethods):  # arrays: a sweep vmaps over them in one program
    learning_rate: float = 3e-4  # Adam's step size
    gamma: float = 0.99  # discount
    epsilon: float = 0.1  # chance of a random action, when acting and in the expectation
    tau: float = 0.02  # step of the target network towards the network, per update


class TrainState(NamedTuple):  # everything a resume needs: rl_jax checkpoints it whole
    params: Any  # the Q-network
    target: Any  # its slowly following copy
    opt_state: Any
    env_state: Any  # [num_envs]
    obs: jax.Array  # [num_envs, obs_size]
    key: jax.Array
    env_steps: jax.Array  # [] env steps of this seed so far
    train_return: jax.Array  # [] mean return of the training episodes last finished
    loss: jax.Array  # [] of the last update


def epsilon_greedy(q: jax.Array, epsilon: jax.Array) -> jax.Array:
    """The policy's probability of each action, [..., actions]."""
    greedy = jax.nn.one_hot(jnp.argmax(q, axis=-1), q.shape[-1])
    return (1.0 - epsilon) * greedy + epsilon / q.shape[-1]


class ExpectedSarsa:
    name = "expected_sarsa"
    policy_fields = ("params",)  # what `policy` reads: rl_jax keeps each seed's best of it

    def default_config(self, env_id: str) -> Config:
        return Config(env_id=env_id)

    def default_hyperparams(self, env_id: str | None = None) -> Hyperparams:
        return Hyperparams().as_arrays()

    def network(self, config: Config) -> nn.Module:
        """Q(s, .): Dense, LayerNorm and ReLU per hidden layer, then one value per action."""
        space = episodes.action_space(config)
        if not isinstance(space, envs.Discrete):  # rl_jax reports it as one line, before a run
            raise TypeError(f"expected SARSA needs discrete actions, not {space}")
        layers = [f for width in config.hidden for f in (nn.Dense(width), nn.LayerNorm(), nn.relu)]
        return nn.Sequential([*layers, nn.Dense(space.n)])

    def optimizer(self, hparams: Hyperparams) -> optax.GradientTransformation:
        return optax.inject_hyperparams(optax.adam)(learning_rate=hparams.learning_rate)

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        params_key, reset_key, key = jax.random.split(key, 3)
        env = episodes.make_train_env(config)  # autoreset, episode statistics
        env_state, ts = jax.vmap(env.reset)(jax.random.split(reset_key, config.num_envs))
        params = self.network(config).init(params_key, ts.obs)
        opt_state = self.optimizer(hparams).init(params)
        steps, zero = jnp.zeros((), jnp.int32), jnp.zeros((), jnp.float32)
        return TrainState(params, params, opt_state, env_state, ts.obs, key, steps, zero, zero)

    def iteration(self, state: TrainState, config: Config, hparams: Hyperparams) -> TrainState:
        network, env = self.network(config), episodes.make_train_env(config)
        key, act_key, step_key = jax.random.split(state.key, 3)
        probs = epsilon_greedy(network.apply(state.params, state.obs), hparams.epsilon)
        action = jax.random.categorical(act_key, jnp.log(probs))
        step_keys = jax.random.split(step_key, config.num_envs)
        env_state, ts = jax.vmap(env.step)(step_keys, state.env_state, action)
        # The state the step reached, also when autoreset began a new episode after it.
        next_q = network.apply(state.target, ts.info["final_obs"])
        expected = jnp.sum(epsilon_greedy(next_q, hparams.epsilon) * next_q, axis=-1)
        # Bootstrap through a time limit, not through a terminal state.
        target = ts.reward + hparams.gamma * (1.0 - ts.terminated) * expected

        def loss_fn(params):
            q = network.apply(params, state.obs)
            q_taken = jnp.take_along_axis(q, action[:, None], axis=-1)[:, 0]
            return jnp.mean((q_taken - target) ** 2)

        loss, grads = jax.value_and_grad(loss_fn)(state.params)
        updates, opt_state = self.optimizer(hparams).update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        done = ts.info["episode_done"]
        finished = jnp.sum(jnp.where(done, ts.info["episode_return"], 0.0)) / jnp.sum(done)
        return TrainState(
            params=params,
            target=optax.incremental_update(params, state.target, hparams.tau),
            opt_state=opt_state,
            env_state=env_state,
            obs=ts.obs,
            key=key,
            env_steps=state.env_steps + config.num_envs,
            train_return=jnp.where(jnp.any(done), finished, state.train_return),
            loss=loss,
        )

    def train_chunk(self, state: TrainState, config: Config, hparams: Hyperparams):
        def body(state, _):
            return self.iteration(state, config, hparams), None

        state, _ = jax.lax.scan(body, state, None, config.iterations_per_chunk)
        key, eval_key = jax.random.split(state.key)
        act, env = jax.vmap(self.policy(state, config)), episodes.make_eval_env(config)
        returns = episodes.episode_returns(act, env, eval_key, config.num_eval_envs)
        metrics = ChunkMetrics(
            env_steps=state.env_steps,
            updates=state.env_steps // config.num_envs,  # one update per iteration
            eval_return=jnp.mean(returns),
            train_return=state.train_return,
            extra={"loss": state.loss},
        )
        return state._replace(key=key), metrics

    def policy(self, state: TrainState, config: Config):
        network, params = self.network(config), state.params
        return lambda obs: jnp.argmax(network.apply(params, obs), axis=-1)  # greedy, one obs


learner = ExpectedSarsa()
