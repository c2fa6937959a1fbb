"""AlphaZero (Silver et al. 2018) with Gumbel root search (Danihelka et al. 2022, "Policy
improvement by planning with Gumbel"), on pgx's two-player board games.

The search is mctx's ``gumbel_muzero_policy`` and its model is the true game: the
``recurrent_fn`` steps the pgx state, and the network only gives each new node its prior and
value. An edge carries the mover's reward and a discount of -1 where the turn passes (+1 where
the same player moves again, 0 where the game ends: ``alphazero_parts.edge_discount``), so
every value in the tree is from the view of the player who chooses there.

One *iteration*: ``num_envs`` games of self-play, vmapped, each from the opening to its end
(``max_game_length`` moves, idle after the end); every move is the search's (Gumbel) sampled
action with ``num_simulations`` simulations. Each position played is stored in a replay of
finished games with two targets: the search's improved policy (mctx's ``action_weights``) and
the game's final outcome from the view of the player to move there
(``alphazero_parts.value_targets``). Then ``updates_per_iteration`` AdamW steps on batches of
``batch_size`` positions drawn uniformly from the replay, on

    loss = cross-entropy(improved policy, network policy) + value_coef * (v - z)^2.

With ``self_play_steps`` > 0 (continuous self-play) each of the ``num_envs`` game slots plays
``self_play_steps`` moves per iteration instead: a game that ends is replaced by a fresh opening
at once, so no search is spent on a finished game; games run on across iterations
(``TrainState.games``), and a game's positions enter the replay, packed, when it ends.

A *chunk* is ``iterations_per_chunk`` iterations, then one evaluation inside the same compiled
call: ``num_eval_games`` games in both colours (ours opens every other one) against the
``eval_opponent``; ``eval_return`` is the mean outcome (1 win, 0 draw, -1 loss). Our side is the
network's greedy policy (no search), or with ``eval_search`` the search itself
(``search_player``, ``num_simulations`` of the config). The opponent is a uniformly random
player (``"random"``, the default: a curve that saturates early), pure MCTS with random
rollouts and ``eval_opponent_simulations`` simulations (``"mcts"``, any game:
``envs.games.rollout_mcts``) or exact tic-tac-toe minimax (``"minimax"``, tic-tac-toe only:
``envs.games.tic_tac_toe_minimax``; it never loses, so 0 is the best score there). Env steps are
counted as move slots, ``num_envs * Config.slot_moves()`` per iteration (``max_game_length``, or
``self_play_steps``); ``moves_played`` in the metrics counts the moves made.

The game is named by the env id ``pgx/GAME`` (``pgx/tic_tac_toe``) and resolved here with
``pgx.make``: the env registry is not involved (docs/learners/alphazero.md says why). Usage::

    config = alphazero.default_config("pgx/tic_tac_toe")
    hparams = alphazero.default_hyperparams("pgx/tic_tac_toe")
    state = alphazero.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(alphazero.train_chunk, static_argnums=1)(state, config, hparams)
    player = alphazero.search_player(state.agent.params, config)  # for envs.games.match
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import NamedTuple, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import mctx
import optax
import pgx
from flax import struct

from rl_jax.agents import alphazero_parts as parts
from rl_jax.agents.common import clip_by_global_norm, injected_step
from rl_jax.envs.games import opponents
from rl_jax.envs.games.match import Player, random_player
from rl_jax.training import algorithm, conv, params
from rl_jax.training.algorithm import ChunkMetrics, Clock, RecipeBook
from rl_jax.training.params import Scalar
from rl_jax.training.recipes import Recipe, Recipes

GAME_PREFIX = "pgx/"
#: The pgx games the search plays: two players, perfect information, no chance moves (pgx's
#: others are one-player, hide cards or roll dice, which a search over the true state misreads).
GAMES = (
    "animal_shogi",
    "chess",
    "connect_four",
    "gardner_chess",
    "go_9x9",
    "go_19x19",
    "hex",
    "othello",
    "shogi",
    "tic_tac_toe",
)
#: Who the evaluation plays against: a uniformly random player, pure MCTS with random rollouts
#: (``envs.games.rollout_mcts``), exact minimax (``envs.games.tic_tac_toe_minimax``, tic-tac-toe
#: only).
EVAL_OPPONENTS = opponents.OPPONENTS


# ---- settings -------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, kw_only=True)
class Config:
    """Static settings (changing one recompiles)."""

    env_id: str = "pgx/tic_tac_toe"  # pgx/GAME: the pgx game, pgx.make(GAME)
    num_envs: int = 64  # self-play games played together (vmapped) per iteration
    max_game_length: int = 9  # moves per self-play game at most (tic-tac-toe: 9)
    # 0: each iteration plays num_envs whole games from the opening, max_game_length moves each
    # (a game over early sits idle, still searched). > 0: continuous self-play: each of the
    # num_envs game slots plays this many moves per iteration, a game that ends is replaced by a
    # fresh opening at once (every search a live move), games run on across iterations, and a
    # game's positions enter the replay when it ends
    self_play_steps: int = 0
    num_simulations: int = 32  # simulations of the search at every self-play move
    max_considered_actions: int = 16  # root actions Gumbel sampling considers
    # self-play moves (from the opening) drawn from the search's improved policy rather than
    # taken as the search's own choice: the games spread over all good lines, not one
    sampled_moves: int = 9
    buffer_size: int = 20_000  # positions the replay keeps (the oldest are overwritten)
    # train on each drawn position or, by a coin flip, its left-right mirror (the same outcome,
    # the mirrored policy): games with that symmetry only, parts.MIRRORED_ACTIONS
    mirror: bool = False
    # the value target's weight on the search's value of the position (its root value, for the
    # player to move) against the game's final outcome: (1 - w) * outcome + w * search value.
    # 0 is AlphaZero's outcome alone; a mix of the two gives a target with less of the noise of
    # one game's ending (docs/learners/alphazero.md)
    search_value_weight: float = 0.0
    batch_size: int = 256  # positions per gradient update
    updates_per_iteration: int = 8  # gradient updates after each batch of self-play games
    iterations_per_chunk: int = 4  # self-play batches and updates per compiled call
    num_eval_games: int = 32  # games per evaluation, half of them opened by each side
    # the evaluation's opponent: random (a uniformly random player), mcts (pure MCTS with random
    # rollouts, eval_opponent_simulations) or minimax (exact, tic-tac-toe only)
    eval_opponent: str = "random"
    eval_opponent_simulations: int = 100  # simulations of the mcts opponent per move
    # evaluate the search (num_simulations, no Gumbel noise) rather than the greedy network
    eval_search: bool = False
    hidden: tuple[int, ...] = (128, 128)  # the torso's Dense + ReLU layers
    # conv layers before them, flat (features, kernel, stride) triples with VALID padding on
    # the board's planes (rl_jax.training.conv.ConvTorso); () for none: the MLP on the
    # flattened board
    conv_layers: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if not self.env_id.startswith(GAME_PREFIX):
            raise ValueError(f"AlphaZero plays pgx games, named pgx/GAME; got {self.env_id!r}")
        if self.env_id.removeprefix(GAME_PREFIX) not in GAMES:
            raise ValueError(
                f"unknown game {self.env_id!r}; AlphaZero plays pgx/GAME for GAME one of "
                + ", ".join(GAMES)
            )
        for name in (
            "num_envs",
            "max_game_length",
            "num_simulations",
            "max_considered_actions",
            "batch_size",
            "updates_per_iteration",
            "iterations_per_chunk",
            "num_eval_games",
            "eval_opponent_simulations",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.self_play_steps < 0:
            raise ValueError(f"self_play_steps must be >= 0, got {self.self_play_steps}")
        if not 0.0 <= self.search_value_weight <= 1.0:
            raise ValueError(
                f"search_value_weight must be in [0, 1], got {self.search_value_weight}"
            )
        if self.conv_layers:
            if len(self.conv_layers) % 3 or min(self.conv_layers) < 1:
                raise ValueError(
                    "conv_layers must be positive (features, kernel, stride) triples, got "
                    f"{self.conv_layers}"
                )
            shape = self.make_game().observation_shape
            conv.check_conv_layers(self.conv_layers, min(shape[0], shape[1]))
        game = self.env_id.removeprefix(GAME_PREFIX)
        if self.mirror and game not in parts.MIRRORED_ACTIONS:
            symmetric = ", ".join(parts.MIRRORED_ACTIONS)
            raise ValueError(
                f"mirror needs a game with a left-right symmetry ({symmetric}), not {game}"
            )
        if self.eval_opponent not in EVAL_OPPONENTS:
            raise ValueError(
                f"eval_opponent must be one of {EVAL_OPPONENTS}, got {self.eval_opponent!r}"
            )
        if self.eval_opponent == "minimax" and self.env_id != GAME_PREFIX + "tic_tac_toe":
            raise ValueError(
                f"eval_opponent 'minimax' is exact tic-tac-toe only, not {self.env_id}; "
                "use 'mcts' (any game) or 'random'"
            )
        # made here, outside any trace: pgx builds module-level arrays when a game's module is
        # first imported, and built inside a jit they would leak as tracers (an unknown game is
        # also named here, before anything compiles)
        self.make_game()
        if self.self_play_steps:
            # an iteration stores the moves of its window and of the unfinished games carried
            # into it, if all of them end in the window
            most = self.num_envs * (self.self_play_steps + self.max_game_length - 1)
            if self.buffer_size < most:
                raise ValueError(
                    f"buffer_size ({self.buffer_size}) must hold the positions one iteration "
                    "can store: num_envs x (self_play_steps + max_game_length - 1) = "
                    f"{most}"
                )
        elif self.buffer_size < self.num_envs * self.max_game_length:
            raise ValueError(
                f"buffer_size ({self.buffer_size}) must hold one iteration's positions: "
                f"num_envs x max_game_length = {self.num_envs * self.max_game_length}"
            )

    def make_game(self) -> pgx.Env:
        """The pgx game ``env_id`` names."""
        return _make_game(self.env_id.removeprefix(GAME_PREFIX))

    def slot_moves(self) -> int:
        """Move slots of each of the ``num_envs`` games per iteration: ``self_play_steps``, or
        ``max_game_length`` with whole games."""
        return self.self_play_steps or self.max_game_length


@functools.cache
def _make_game(name: str) -> pgx.Env:
    # one object per game, so that compiled matches keyed by it are reused
    return pgx.make(name)


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling."""

    learning_rate: Scalar = 1e-3  # AdamW's step size
    weight_decay: Scalar = 1e-4  # AdamW's decoupled weight decay
    value_coef: Scalar = 1.0  # weight of the value loss beside the policy loss
    max_grad_norm: Scalar = 1.0  # clip the gradient's global norm to this (0: no clipping)
    # chance that a self-play move is a uniformly random legal one: games where one side
    # blunders teach the value of lost and won positions, which play between two equal and
    # careful sides never reaches
    random_move_prob: Scalar = 0.1


# ---- the network and the state --------------------------------------------------------------
class PolicyValueNet(nn.Module):
    """Observations ``[N, *obs_shape]`` -> ``(logits [N, A], value [N] in [-1, 1])``: an MLP
    torso on the flattened observation (after ``conv_layers`` on the board's planes, if any), a
    linear policy head and a tanh value head."""

    num_actions: int
    hidden: tuple[int, ...]
    conv_layers: tuple[int, ...] = ()

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        if self.conv_layers:
            obs = conv.ConvTorso(self.conv_layers, high=1.0)(obs)
        x = obs.reshape(obs.shape[0], -1).astype(jnp.float32)
        for width in self.hidden:
            x = nn.relu(nn.Dense(width)(x))
        logits = nn.Dense(self.num_actions)(x)
        value = jnp.tanh(nn.Dense(1)(x))[:, 0]
        return logits, value


def evaluate_net(
    network: PolicyValueNet, net_params: optax.Params, obs: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """``(logits [N, A], value [N])`` of the network on observations ``[N, *obs_shape]``."""
    logits, value = network.apply(net_params, obs)
    return cast(jax.Array, logits), cast(jax.Array, value)


def make_network(config: Config) -> PolicyValueNet:
    """The policy and value network for the config's game."""
    return PolicyValueNet(
        num_actions=config.make_game().num_actions,
        hidden=config.hidden,
        conv_layers=config.conv_layers,
    )


class Agent(NamedTuple):
    """What the policy reads, and its optimizer."""

    params: optax.Params
    opt_state: optax.OptState


class Replay(NamedTuple):
    """Positions of finished self-play games, a ring of ``buffer_size`` rows."""

    obs: jax.Array  # [C, *obs_shape]
    legal: jax.Array  # [C, A] bool
    policy: jax.Array  # [C, A] the search's improved policy
    value: jax.Array  # [C] the final outcome for the player to move
    # [C] 1 for a position played, 0 for an idle step after a game's end (whole-game
    # self-play only: continuous self-play stores no idle step)
    weight: jax.Array
    value_weight: jax.Array  # [C] 1 where no random move followed it in its game
    position: jax.Array  # [] int32, the next row to write
    size: jax.Array  # [] int32, rows written so far (at most C)


class Positions(NamedTuple):
    """The positions of one self-play batch, time-major ``[T, B, ...]``."""

    obs: jax.Array
    legal: jax.Array
    policy: jax.Array  # the search's improved policy
    player: jax.Array  # the player to move
    rewards: jax.Array  # [T, B, P] what each player received from the move
    alive: jax.Array  # 1 before the game ended
    explored: jax.Array  # 1 where the move played was a random one
    ended: jax.Array  # 1 where the move ended its game (or was its max_game_length-th)
    # the search's root value for the player to move; None unless the value target mixes it in
    # (Config.search_value_weight), so that the state is AlphaZero's own without it
    search_value: jax.Array | None = None


class Games(NamedTuple):
    """Continuous self-play's games in progress, one per slot (``self_play_steps`` > 0)."""

    states: pgx.State  # [B] the position each slot's game moves from next
    # [max_game_length - 1, B] the positions each slot's game has played so far, the last rows
    # (alive 1 on its moves, 0 on the rows before): they get their targets when it ends
    unfinished: Positions


@struct.dataclass
class TrainState:
    """Everything one seed's run needs to go on."""

    agent: Agent
    replay: Replay
    key: jax.Array
    clock: Clock
    moves_played: jax.Array  # [] int32, moves made in self-play so far
    games: Games | None = None  # continuous self-play's games (None: whole games)


# ---- the search -----------------------------------------------------------------------------
def _recurrent_fn(network: PolicyValueNet, game: pgx.Env) -> mctx.RecurrentFn:
    """mctx's model: the true game steps, the network values and guides the new node."""

    def recurrent_fn(
        net_params: optax.Params, key: jax.Array, action: jax.Array, state: pgx.State
    ) -> tuple[mctx.RecurrentFnOutput, pgx.State]:
        mover = state.current_player
        next_state = jax.vmap(game.step)(state, action, jax.random.split(key, action.shape[0]))
        logits, value = evaluate_net(network, net_params, next_state.observation)
        reward = jnp.take_along_axis(next_state.rewards, mover[:, None], axis=1)[:, 0]
        output = mctx.RecurrentFnOutput(
            reward=reward,
            discount=parts.edge_discount(mover, next_state.current_player, next_state.terminated),
            prior_logits=parts.masked_logits(logits, next_state.legal_action_mask),
            value=jnp.where(next_state.terminated, 0.0, value),
        )
        return output, next_state

    return recurrent_fn


def search(
    net_params: optax.Params,
    states: pgx.State,
    key: jax.Array,
    config: Config,
    num_simulations: int | None = None,
    gumbel_scale: float = 1.0,
) -> mctx.PolicyOutput:
    """Gumbel MuZero's root search from a batch of pgx states with the true game as the model;
    ``num_simulations`` None: the config's. ``gumbel_scale`` 0 makes it deterministic."""
    network, game = make_network(config), config.make_game()
    logits, value = evaluate_net(network, net_params, states.observation)
    root = mctx.RootFnOutput(prior_logits=logits, value=value, embedding=states)
    return mctx.gumbel_muzero_policy(
        net_params,
        key,
        root,
        _recurrent_fn(network, game),
        num_simulations or config.num_simulations,
        invalid_actions=~states.legal_action_mask,
        max_num_considered_actions=config.max_considered_actions,
        gumbel_scale=gumbel_scale,
    )


def search_player(
    net_params: optax.Params, config: Config, num_simulations: int | None = None
) -> Player:
    """A player for one pgx state (``envs.games.match.Player``): the deterministic search's
    move (no Gumbel noise)."""

    def player(state: pgx.State, key: jax.Array) -> jax.Array:
        states = jax.tree.map(lambda leaf: leaf[None], state)
        output = search(net_params, states, key, config, num_simulations, gumbel_scale=0.0)
        return output.action[0].astype(jnp.int32)

    return player


def network_player(net_params: optax.Params, config: Config) -> Player:
    """A player for one pgx state: the network's most likely legal move, without search."""
    network = make_network(config)

    def player(state: pgx.State, key: jax.Array) -> jax.Array:
        del key
        logits, _ = evaluate_net(network, net_params, state.observation[None])
        return jnp.argmax(parts.masked_logits(logits[0], state.legal_action_mask)).astype(jnp.int32)

    return player


# ---- self-play and the replay ---------------------------------------------------------------
def _play_move(
    net_params: optax.Params,
    states: pgx.State,
    key: jax.Array,
    move_number: jax.Array,
    config: Config,
    hparams: Hyperparams,
) -> tuple[pgx.State, Positions]:
    """One searched move in each of the ``num_envs`` games: the states after it and the
    positions it was made from (``move_number``: of each game, from its opening)."""
    game = config.make_game()
    search_key, sample_key, random_key, step_key = jax.random.split(key, 4)
    output = search(net_params, states, search_key, config)
    sampled = jax.random.categorical(sample_key, jnp.log(output.action_weights))
    action = jnp.where(move_number < config.sampled_moves, sampled, output.action)
    random_keys = jax.random.split(random_key, (2, config.num_envs))
    explore = jax.vmap(jax.random.uniform)(random_keys[0]) < hparams.random_move_prob
    random_moves = jax.vmap(random_player)(states, random_keys[1])
    action = jnp.where(explore, random_moves, action)
    step_keys = jax.random.split(step_key, config.num_envs)
    next_states = jax.vmap(game.step)(states, action, step_keys)
    alive = ~(states.terminated | states.truncated)
    over = next_states.terminated | next_states.truncated
    played = Positions(
        obs=states.observation,
        legal=states.legal_action_mask,
        policy=output.action_weights,
        player=states.current_player,
        rewards=next_states.rewards,
        alive=alive.astype(jnp.float32),
        explored=explore.astype(jnp.float32),
        ended=(alive & (over | (next_states._step_count >= config.max_game_length))).astype(
            jnp.float32
        ),
        search_value=output.search_tree.summary().value if config.search_value_weight else None,
    )
    return next_states, played


def self_play(
    net_params: optax.Params, key: jax.Array, config: Config, hparams: Hyperparams
) -> Positions:
    """``num_envs`` games from the opening, every move the search's, ``max_game_length`` steps."""
    game = config.make_game()
    init_key, key = jax.random.split(key)
    states = jax.vmap(game.init)(jax.random.split(init_key, config.num_envs))

    def move(states: pgx.State, step: tuple[jax.Array, jax.Array]) -> tuple[pgx.State, Positions]:
        key, move_number = step
        return _play_move(net_params, states, key, move_number, config, hparams)

    steps = (jax.random.split(key, config.max_game_length), jnp.arange(config.max_game_length))
    _, positions = jax.lax.scan(move, states, steps)
    return positions


def continuous_self_play(
    net_params: optax.Params,
    states: pgx.State,
    key: jax.Array,
    config: Config,
    hparams: Hyperparams,
) -> tuple[pgx.State, Positions]:
    """``self_play_steps`` searched moves in each of the ``num_envs`` slots, on from ``states``;
    a game that ends (or reaches ``max_game_length`` moves) is replaced at once by a fresh
    opening, so every search is of a live position. ``(states after, positions [T, B])``; each
    game's first ``sampled_moves`` moves, counted from its own opening, are drawn from the
    improved policy."""
    game = config.make_game()

    def move(states: pgx.State, key: jax.Array) -> tuple[pgx.State, Positions]:
        move_key, init_key = jax.random.split(key)
        next_states, played = _play_move(
            net_params, states, move_key, states._step_count, config, hparams
        )
        fresh = jax.vmap(game.init)(jax.random.split(init_key, config.num_envs))
        ended = played.ended > 0

        def restart(new: jax.Array, old: jax.Array) -> jax.Array:
            return jnp.where(ended.reshape(-1, *(1,) * (old.ndim - 1)), new, old)

        return jax.tree.map(restart, fresh, next_states), played

    return jax.lax.scan(move, states, jax.random.split(key, config.self_play_steps))


def replay_init(config: Config) -> Replay:
    """An empty replay for the config's game."""
    game, capacity = config.make_game(), config.buffer_size
    obs = jax.eval_shape(game.init, jax.random.key(0)).observation
    return Replay(
        obs=jnp.zeros((capacity, *obs.shape), obs.dtype),
        legal=jnp.zeros((capacity, game.num_actions), jnp.bool_),
        policy=jnp.zeros((capacity, game.num_actions), jnp.float32),
        value=jnp.zeros((capacity,), jnp.float32),
        weight=jnp.zeros((capacity,), jnp.float32),
        value_weight=jnp.zeros((capacity,), jnp.float32),
        position=jnp.int32(0),
        size=jnp.int32(0),
    )


def _write(
    replay: Replay,
    positions: Positions,
    targets: tuple[jax.Array, ...],
    rows: jax.Array,
    count: int | jax.Array,
) -> Replay:
    """The replay with ``positions`` (``[T, B]``) and their ``targets`` (value, weight, value
    weight) scattered, flattened, to ``rows`` (an out-of-range row drops its entry), and
    ``count`` rows more written."""
    fields = (positions.obs, positions.legal, positions.policy, *targets)
    flat = (x.reshape(-1, *x.shape[2:]) for x in fields)
    capacity = replay.value.shape[0]
    written = (
        old.at[rows].set(new, mode="drop") for old, new in zip(replay[:6], flat, strict=True)
    )
    return Replay._make(
        (*written, (replay.position + count) % capacity, jnp.minimum(replay.size + count, capacity))
    )


def _mixed(outcomes: jax.Array, positions: Positions, config: Config) -> jax.Array:
    """The value targets: the outcomes, mixed with the search's values where
    ``search_value_weight`` says so."""
    if positions.search_value is None:
        return outcomes
    return parts.mixed_value_targets(
        outcomes, positions.search_value, config.search_value_weight, positions.alive
    )


def replay_add(replay: Replay, positions: Positions, config: Config) -> Replay:
    """The replay with a finished batch's positions and their targets written over its oldest."""
    outcomes = parts.value_targets(positions.rewards, positions.player, positions.alive)
    targets = _mixed(outcomes, positions, config)
    weights = (positions.alive, parts.played_on(positions.explored, positions.alive))
    count = positions.alive.size
    rows = (replay.position + jnp.arange(count)) % replay.value.shape[0]
    return _write(replay, positions, (targets, *weights), rows, count)


def games_init(key: jax.Array, config: Config) -> Games:
    """Continuous self-play's ``num_envs`` games at their openings, nothing played yet."""
    game, slots = config.make_game(), config.num_envs
    states = jax.vmap(game.init)(jax.random.split(key, slots))
    # the unused rows before a carried game: a move's fields, all zero
    policy = jnp.zeros((slots, game.num_actions), jnp.float32)
    flag = jnp.zeros(slots, jnp.float32)
    move = Positions(
        states.observation, states.legal_action_mask, policy, states.current_player,
        states.rewards, flag, flag, flag, flag if config.search_value_weight else None,
    )  # fmt: skip
    rows = config.max_game_length - 1
    unfinished = jax.tree.map(lambda x: jnp.zeros((rows, *x.shape), x.dtype), move)
    return Games(states=states, unfinished=unfinished)


def replay_add_games(
    replay: Replay, positions: Positions, carried_rows: int, config: Config
) -> tuple[Replay, Positions, jax.Array]:
    """Continuous self-play's write: of ``positions`` (``[T, B]``, a slot's games back to back,
    its unfinished game carried in first), the moves of the games that ended, packed
    (``alphazero_parts.compacted_rows``: the others take no row), with their own game's
    targets. ``(replay, the unfinished games' positions as the last carried_rows rows, rows
    written)``."""
    finished = parts.game_finished(positions.ended, positions.alive)
    outcomes = parts.game_value_targets(
        positions.rewards, positions.player, positions.alive, positions.ended
    )
    targets = (
        _mixed(outcomes, positions, config),
        finished,
        parts.game_played_on(positions.explored, positions.alive, positions.ended),
    )
    rows = parts.compacted_rows(finished.reshape(-1), replay.position, replay.value.shape[0])
    count = jnp.sum(finished).astype(jnp.int32)
    replay = _write(replay, positions, targets, rows, count)
    # only a slot's last game can be unfinished, with fewer than max_game_length moves: its
    # positions are the slot's last rows, and the rows before them are marked as holding none
    start = positions.alive.shape[0] - carried_rows
    unfinished = jax.tree.map(lambda x: x[start:], positions)
    return replay, unfinished._replace(alive=(positions.alive - finished)[start:]), count


# ---- training -------------------------------------------------------------------------------
def loss_fn(
    net_params: optax.Params, batch: Replay, hparams: Hyperparams, config: Config
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(loss, metrics)`` of a batch of replayed positions."""
    logits, value = evaluate_net(make_network(config), net_params, batch.obs)
    policy_loss = parts.policy_loss(logits, batch.policy, batch.legal, batch.weight)
    value_loss = parts.value_loss(value, batch.value, batch.value_weight)
    total = policy_loss + hparams.value_coef * value_loss
    return total, {"policy_loss": policy_loss, "value_loss": value_loss}


def _adamw(learning_rate: Scalar, weight_decay: Scalar) -> optax.GradientTransformation:
    return optax.adamw(learning_rate, weight_decay=weight_decay)


def update(
    agent: Agent, replay: Replay, key: jax.Array, hparams: Hyperparams, config: Config
) -> tuple[Agent, dict[str, jax.Array]]:
    """One AdamW step on ``batch_size`` positions drawn uniformly from the replay."""
    rows = jax.random.randint(key, (config.batch_size,), 0, jnp.maximum(replay.size, 1))
    batch = Replay._make([*(field[rows] for field in replay[:6]), replay.position, replay.size])
    if config.mirror:  # a key of its own, so that the rows drawn are those without the option
        flip = jax.random.bernoulli(jax.random.fold_in(key, 1), 0.5, (config.batch_size,))
        actions = parts.MIRRORED_ACTIONS[config.env_id.removeprefix(GAME_PREFIX)]
        obs, legal, policy = parts.mirrored(flip, batch.obs, batch.legal, batch.policy, actions)
        batch = batch._replace(obs=obs, legal=legal, policy=policy)
    grads, metrics = jax.grad(loss_fn, has_aux=True)(agent.params, batch, hparams, config)
    grads, metrics["grad_norm"] = clip_by_global_norm(grads, hparams.max_grad_norm)
    net_params, opt_state = injected_step(
        _adamw,
        grads,
        agent.opt_state,
        agent.params,
        learning_rate=hparams.learning_rate,
        weight_decay=hparams.weight_decay,
    )
    return Agent(net_params, opt_state), metrics


def train_iteration(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, dict[str, jax.Array]]:
    """One batch of self-play games (whole games, or with ``self_play_steps`` a window of
    continuous self-play) into the replay, then ``updates_per_iteration`` updates (none while
    continuous self-play's replay is still empty)."""
    key, play_key, update_key = jax.random.split(state.key, 3)
    games, extra = state.games, {}
    if games is None:
        positions = self_play(state.agent.params, play_key, config, hparams)
        replay = replay_add(state.replay, positions, config)
    else:
        states, positions = continuous_self_play(
            state.agent.params, games.states, play_key, config, hparams
        )
        carried = games.unfinished
        replay, unfinished, extra["positions_stored"] = replay_add_games(
            state.replay,
            jax.tree.map(lambda a, b: jnp.concatenate([a, b]), carried, positions),
            carried.alive.shape[0],
            config,
        )
        games = Games(states=states, unfinished=unfinished)

    def one_update(agent: Agent, key: jax.Array) -> tuple[Agent, dict[str, jax.Array]]:
        return update(agent, replay, key, hparams, config)

    def updates(agent: Agent) -> tuple[Agent, dict[str, jax.Array]]:
        return jax.lax.scan(one_update, agent, update_keys)

    update_keys = jax.random.split(update_key, config.updates_per_iteration)
    if games is None:
        agent, metrics = updates(state.agent)
    else:
        # continuous self-play stores a game only when it ends, so the replay can still be empty
        # (the first iterations of a run): updates on it would see zero gradients yet still
        # decay the weights and advance Adam's step count, so they are skipped, with zero
        # metrics. The clock counts them all the same (it depends on the config alone).
        skipped = jax.tree.map(
            lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(updates, state.agent)[1]
        )
        agent, metrics = jax.lax.cond(
            replay.size > 0, updates, lambda agent: (agent, skipped), state.agent
        )
        extra["updated"] = (replay.size > 0).astype(jnp.float32)
    clock = state.clock
    state = TrainState(
        agent=agent,
        replay=replay,
        key=key,
        clock=Clock(
            env_steps=clock.env_steps + config.num_envs * config.slot_moves(),
            updates=clock.updates + config.updates_per_iteration,
            iterations=clock.iterations + 1,
        ),
        moves_played=state.moves_played + jnp.sum(positions.alive).astype(jnp.int32),
        games=games,
    )
    return state, {**jax.tree.map(jnp.mean, metrics), **extra}


def eval_opponent_player(config: Config) -> Player:
    """The evaluation's opponent, a player for one pgx state: ``config.eval_opponent``
    (``envs.games.opponents``)."""
    game = config.make_game()
    return opponents.opponent_player(config.eval_opponent, game, config.eval_opponent_simulations)


def eval_player(net_params: optax.Params, config: Config) -> Player:
    """Our side in the evaluation: the search (``search_player``) with ``eval_search``, else the
    greedy network (``network_player``)."""
    if config.eval_search:
        return search_player(net_params, config)
    return network_player(net_params, config)


def evaluate(net_params: optax.Params, key: jax.Array, config: Config) -> jax.Array:
    """The mean outcome (1 win, 0 draw, -1 loss) of our side (``eval_player``: the greedy
    network, or the search with ``eval_search``) against ``eval_opponent`` (a uniformly random
    player by default) over ``num_eval_games`` games, opening in every other one."""
    game, learner = config.make_game(), eval_player(net_params, config)
    opponent = eval_opponent_player(config)
    init_key, key = jax.random.split(key)
    states = jax.vmap(game.init)(jax.random.split(init_key, config.num_eval_games))
    opens = jnp.arange(config.num_eval_games) % 2 == 0
    learner_id = jnp.where(opens, states.current_player, 1 - states.current_player)

    def move(carry: tuple[pgx.State, jax.Array], key: jax.Array) -> tuple[tuple, None]:
        states, total = carry
        keys = jax.random.split(key, (2, config.num_eval_games))
        ours = jax.vmap(learner)(states, keys[0])
        theirs = jax.vmap(opponent)(states, keys[1])
        action = jnp.where(states.current_player == learner_id, ours, theirs)
        states = jax.vmap(game.step)(states, action, keys[1])
        reward = jnp.take_along_axis(states.rewards, learner_id[:, None], axis=1)[:, 0]
        return (states, total + reward), None

    keys = jax.random.split(key, config.max_game_length)
    (_, total), _ = jax.lax.scan(move, (states, jnp.zeros(config.num_eval_games)), keys)
    return jnp.mean(total)


def init(key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
    """A fresh state for one seed and one hyperparameter set."""
    net_key, key = jax.random.split(key)
    replay = replay_init(config)
    net_params = make_network(config).init(net_key, replay.obs[:1])
    optimizer = optax.inject_hyperparams(_adamw)(hparams.learning_rate, hparams.weight_decay)
    zero, games = jnp.int32(0), None
    if config.self_play_steps:
        games_key, key = jax.random.split(key)
        games = games_init(games_key, config)
    return TrainState(
        agent=Agent(net_params, optimizer.init(net_params)),
        replay=replay,
        key=key,
        clock=Clock(env_steps=zero, updates=zero, iterations=zero),
        moves_played=zero,
        games=games,
    )


def chunk_means(metrics: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """The chunk's mean of each iteration's metrics. With continuous self-play (an
    ``updated`` flag per iteration) the update metrics average the iterations that updated only,
    so that skipped updates' zeros do not pull the losses down (0 where none updated);
    ``updated`` becomes the fraction of iterations that did."""
    if "updated" not in metrics:
        return jax.tree.map(jnp.mean, metrics)
    updated = metrics["updated"]
    count = jnp.maximum(jnp.sum(updated), 1.0)
    not_updates = ("updated", "positions_stored")
    return {  # each value holds one scalar per iteration
        name: jnp.mean(value) if name in not_updates else jnp.sum(value * updated) / count
        for name, value in metrics.items()
    }


def train_chunk(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, ChunkMetrics]:
    """``iterations_per_chunk`` self-play batches and updates, then one evaluation. Pure."""
    state, metrics = jax.lax.scan(
        lambda s, _: train_iteration(s, config, hparams),
        state,
        None,
        length=config.iterations_per_chunk,
    )
    eval_key, key = jax.random.split(state.key)
    eval_return = evaluate(state.agent.params, eval_key, config)
    state = dataclasses.replace(state, key=key)
    extra = {**chunk_means(metrics), "moves_played": state.moves_played}
    return state, ChunkMetrics(
        env_steps=state.clock.env_steps,
        updates=state.clock.updates,
        eval_return=eval_return,
        train_return=jnp.float32(0.0),  # self-play is zero-sum: its mean return says nothing
        extra=extra,
    )


# ---- the Algorithm object -------------------------------------------------------------------
#: Env steps (move slots) of one chunk under the default config: 64 games x 9 moves x 4.
_TIC_TAC_TOE_CHUNK = 64 * 9 * 4

RECIPES = Recipes(
    Recipe(
        "default",
        "128x128 MLP, 64 games x 32 simulations; 500 chunks draw exact minimax",
        envs=("pgx/tic_tac_toe",),
        total_steps=500 * _TIC_TAC_TOE_CHUNK,
    ),
    # Continuous self-play: whole games leave about two thirds of Connect Four's 64 x 42 move
    # slots idle once their games have ended. Mirrored positions, 32 updates an iteration (each
    # position drawn about 3 times) and value targets half the search's value make more of
    # every game (docs/learners/alphazero.md).
    Recipe(
        "default",
        "256x256 MLP, 64 games x 42 moves of continuous self-play x 32 simulations, "
        "32 updates an iteration on mirrored positions, value targets half the search's",
        config={
            "max_game_length": 42,
            "sampled_moves": 12,
            "hidden": (256, 256),
            "self_play_steps": 42,
            "buffer_size": 40_000,
            "mirror": True,
            "updates_per_iteration": 32,
            "search_value_weight": 0.5,
        },
        envs=("pgx/connect_four",),
    ),
)


class AlphaZero(RecipeBook):
    """AlphaZero as an ``rl_jax.training.algorithm.Algorithm``. It owns its envs (``owns_env``:
    every ``pgx/...`` id), so the run machinery keeps them out of the env registry, and
    ``load_policy`` gives the search's move for a pgx state (``position_policy``)."""

    name = "alphazero"
    config_type, hparams_type = Config, Hyperparams
    recipes = RECIPES
    policy_fields = ("agent",)

    def init(self, key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
        """A fresh state for one seed and one hyperparameter set."""
        return init(key, config, hparams)

    def train_chunk(
        self, state: TrainState, config: Config, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        """``iterations_per_chunk`` self-play batches and updates, then one evaluation."""
        return train_chunk(state, config, hparams)

    def env_steps_per_chunk(self, config: Config) -> int:
        """Move slots per chunk: ``num_envs * slot_moves() * iterations_per_chunk``
        (``slot_moves``: ``self_play_steps``, or ``max_game_length`` with whole games)."""
        return config.num_envs * config.slot_moves() * config.iterations_per_chunk

    def owns_env(self, env_id: str) -> bool:
        """Every ``pgx/...`` id: the learner makes the game itself (an unknown game is refused
        by its ``Config``, naming the games it plays)."""
        return env_id.startswith(GAME_PREFIX)

    def position_policy(self, state: algorithm.TrainState, config: Config) -> Player:
        """``(pgx_state, key) -> action``: the search's move (``search_player``, no Gumbel
        noise) with the trained network, ``num_simulations`` of the config."""
        return search_player(cast(TrainState, state).agent.params, config)

    def policy(self, state: TrainState, config: Config) -> Callable[..., jax.Array]:
        """``(obs, legal) -> action``: the network's most likely legal move, without search."""
        network = make_network(config)

        def act(obs: jax.Array, legal: jax.Array) -> jax.Array:
            logits, _ = evaluate_net(network, state.agent.params, obs[None])
            return jnp.argmax(parts.masked_logits(logits[0], legal)).astype(jnp.int32)

        return act


alphazero = AlphaZero()
default_config, default_hyperparams = alphazero.default_config, alphazero.default_hyperparams
