"""A planner of the user's own: afterstate values learned by TD(0) self-play, one ply of search.

V(observation) in [-1, 1] is the outcome for the player to move (pgx observations are the
mover's view). To choose, the planner steps a copy of the pgx state through every action with
the true game: a move that ends the game is worth the mover's reward, any other -V of the
position it reaches (the opponent moves there). Self-play: every game of a seed takes one
epsilon-greedy move per iteration, and V(s) moves towards that same value of the move played,
under a slowly following copy of V. It owns its env (``owns_env``). Guide: docs/own_learner.md.

    python experiments/train.py --algo examples/afterstate_planner.py:learner --env pgx/tic_tac_toe
"""

import dataclasses
import functools
from collections.abc import Callable
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
import pgx
from flax import struct

from rl_jax.envs.games.match import random_player
from rl_jax.training.algorithm import ChunkMetrics
from rl_jax.training.params import HyperparamsMethods

GAMES = ("pgx/tic_tac_toe", "pgx/connect_four")


@functools.cache
def make_game(env_id: str) -> pgx.Env:
    # once per game, outside any trace: pgx builds module-level arrays on its first import
    return pgx.make(env_id.removeprefix("pgx/"))


@dataclasses.dataclass(frozen=True)
class Config:  # static: shapes and loop lengths; a change compiles another program
    env_id: str = "pgx/tic_tac_toe"
    num_envs: int = 32  # self-play games of one seed, one move each per iteration
    iterations_per_chunk: int = 100  # moves of every game between two evaluations
    hidden: tuple[int, ...] = (64,)  # widths of the value network's hidden layers
    num_eval_games: int = 32  # games against a random player per evaluation, half opened by us

    def __post_init__(self) -> None:
        if self.env_id not in GAMES:  # one error line, before anything compiles
            raise ValueError(f"the afterstate planner plays {', '.join(GAMES)}, not {self.env_id}")
        make_game(self.env_id)


@struct.dataclass
class Hyperparams(HyperparamsMethods):  # arrays: a sweep vmaps over them in one program
    learning_rate: float = 1e-3  # Adam's step size
    epsilon: float = 0.2  # chance of a random legal move in self-play
    tau: float = 0.05  # step of the target network towards the network, per update


class TrainState(NamedTuple):  # everything a resume needs: rl_jax checkpoints it whole
    params: optax.Params  # the value network
    target: optax.Params  # its slowly following copy, for the TD targets
    opt_state: optax.OptState
    games: pgx.State  # [num_envs] the self-play positions: pgx states, stepped in place
    key: jax.Array
    env_steps: jax.Array  # [] moves played by this seed so far
    loss: jax.Array  # [] of the last update


def network(config: Config) -> nn.Module:
    """V(observation): Dense and ReLU per hidden layer on the flattened board, then tanh."""
    layers = [f for width in config.hidden for f in (nn.Dense(width), nn.relu)]
    flat = lambda obs: obs.reshape(*obs.shape[:-3], -1).astype(jnp.float32)  # noqa: E731
    return nn.Sequential([flat, *layers, nn.Dense(1), lambda v: jnp.tanh(v[..., 0])])


def search(params: optax.Params, state: pgx.State, config: Config) -> tuple[jax.Array, pgx.State]:
    """One ply from one position: the value of every action for the mover, [A] (-inf where
    illegal), and the positions the actions reach, [A] (copies of the state, stepped)."""
    game = make_game(config.env_id)
    after = jax.vmap(game.step, in_axes=(None, 0))(state, jnp.arange(game.num_actions))
    reward = after.rewards[:, state.current_player]  # the mover's, where the game ended
    values = jnp.where(after.terminated, reward, -network(config).apply(params, after.observation))
    return jnp.where(state.legal_action_mask, values, -jnp.inf), after


def planner(params: optax.Params, config: Config) -> Callable[[pgx.State, jax.Array], jax.Array]:
    """``(state, key) -> action``, the greedy one-ply move: a player of rl_jax.envs.games.match."""
    return lambda state, key: jnp.argmax(search(params, state, config)[0]).astype(jnp.int32)


def evaluate(params: optax.Params, key: jax.Array, config: Config) -> jax.Array:
    """The mean outcome (1 win, 0 draw, -1 loss) of the planner against a random player, which
    opens the odd games."""
    game, n, ours = make_game(config.env_id), config.num_eval_games, planner(params, config)
    init_key, key = jax.random.split(key)
    states = jax.vmap(game.init)(jax.random.split(init_key, n))
    us = jnp.where(jnp.arange(n) % 2 == 0, states.current_player, 1 - states.current_player)

    def move(carry):  # one move of every game; a finished game idles (pgx leaves it as it is)
        states, total, key = carry
        key, random_key, step_key = jax.random.split(key, 3)
        random_keys, step_keys = jax.random.split(random_key, n), jax.random.split(step_key, n)
        theirs = jax.vmap(random_player)(states, random_keys)
        action = jnp.where(states.current_player == us, jax.vmap(ours)(states, step_keys), theirs)
        states = jax.vmap(game.step)(states, action, step_keys)
        return states, total + states.rewards[jnp.arange(n), us], key

    running = lambda carry: ~jnp.all(carry[0].terminated | carry[0].truncated)  # noqa: E731
    _, total, _ = jax.lax.while_loop(running, move, (states, jnp.zeros(n), key))
    return jnp.mean(total)


def restart(ended: jax.Array, fresh: pgx.State, game: pgx.State) -> pgx.State:
    """One game's next position: the fresh opening where it ended, else as it is."""
    return jax.tree.map(lambda new, old: jnp.where(ended, new, old), fresh, game)


def adam(hparams: Hyperparams) -> optax.GradientTransformation:
    return optax.inject_hyperparams(optax.adam)(learning_rate=hparams.learning_rate)


class AfterstatePlanner:
    name = "afterstate_planner"
    policy_fields = ("params",)  # what the policies read: rl_jax keeps each seed's best of it

    def owns_env(self, env_id: str) -> bool:  # it builds pgx/GAME itself; Config names GAMES
        return env_id.startswith("pgx/")

    def default_config(self, env_id: str) -> Config:
        return Config(env_id=env_id)

    def default_hyperparams(self, env_id: str | None = None) -> Hyperparams:
        return Hyperparams().as_arrays()

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        params_key, games_key, key = jax.random.split(key, 3)
        new_game = jax.vmap(make_game(config.env_id).init)
        games = new_game(jax.random.split(games_key, config.num_envs))
        params = network(config).init(params_key, games.observation)
        steps, zero = jnp.zeros((), jnp.int32), jnp.zeros((), jnp.float32)
        return TrainState(params, params, adam(hparams).init(params), games, key, steps, zero)

    def iteration(self, state: TrainState, config: Config, hparams: Hyperparams) -> TrainState:
        games, rows = state.games, jnp.arange(config.num_envs)
        key, explore_key, random_key, reset_key = jax.random.split(state.key, 4)
        values, reached = jax.vmap(search, in_axes=(None, 0, None))(state.params, games, config)
        explore = jax.random.uniform(explore_key, (config.num_envs,)) < hparams.epsilon
        random_moves = jax.vmap(random_player)(games, jax.random.split(random_key, len(rows)))
        action = jnp.where(explore, random_moves, jnp.argmax(values, axis=1))
        after = jax.tree.map(lambda x: x[rows, action], reached)  # the search stepped there
        # TD(0): the mover's reward where the move ended the game, else -V'(the next position)
        next_value = network(config).apply(state.target, after.observation)
        target = jnp.where(after.terminated, after.rewards[rows, games.current_player], -next_value)

        def loss_fn(params):
            return jnp.mean((network(config).apply(params, games.observation) - target) ** 2)

        loss, grads = jax.value_and_grad(loss_fn)(state.params)
        updates, opt_state = adam(hparams).update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        # a game that ended starts again in its slot, from a fresh opening
        fresh = jax.vmap(make_game(config.env_id).init)(jax.random.split(reset_key, len(rows)))
        games = jax.vmap(restart)(after.terminated | after.truncated, fresh, after)
        target = optax.incremental_update(params, state.target, hparams.tau)
        steps = state.env_steps + config.num_envs  # a move of every game
        return TrainState(params, target, opt_state, games, key, steps, loss)

    def train_chunk(self, state: TrainState, config: Config, hparams: Hyperparams):
        def body(state, _):
            return self.iteration(state, config, hparams), None

        state, _ = jax.lax.scan(body, state, None, config.iterations_per_chunk)
        key, eval_key = jax.random.split(state.key)
        metrics = ChunkMetrics(
            env_steps=state.env_steps,
            updates=state.env_steps // config.num_envs,  # one update per iteration
            eval_return=evaluate(state.params, eval_key, config),
            train_return=jnp.float32(0.0),  # self-play is zero-sum: its mean says nothing
            extra={"loss": state.loss},
        )
        return state._replace(key=key), metrics

    def position_policy(self, state: TrainState, config: Config):
        """``(pgx_state, key) -> action``: the planner's move (``GamePolicy.move``, matches)."""
        return planner(state.params, config)

    def policy(self, state: TrainState, config: Config):
        """``(obs, legal) -> action`` for a caller with an observation only: the search needs
        the pgx state, so this is the first legal move; ``GamePolicy.move`` plays the planner."""
        return lambda obs, legal: jnp.argmax(legal).astype(jnp.int32)


learner = AfterstatePlanner()
