"""A trained policy out of a run directory, for rendering and for the user's own code.

    import gymnasium, rl_jax

    policy = rl_jax.load_policy("runs/td3_cheetah")      # the best seed's best policy
    env = gymnasium.make("HalfCheetah-v5")
    obs, _ = env.reset(seed=0)
    for _ in range(1000):
        obs, reward, terminated, truncated, _ = env.step(policy(obs))

``which="best"`` (the default) is the policy of the seed's best evaluation, kept in
``RUN_DIR/best/`` by the runner; ``which="latest"`` is the one of the latest checkpoint. Without
a seed, the seed (and sweep config) with the highest such eval return is chosen.

A run of a learner of the user's own is opened with that learner named again
(``load_policy(run_dir, algorithm="my_learner.py:learner")``, or the object), and a run on an
env of the user's own module with that env named again (``env="my_envs:Hover-v0"``): a run
directory never makes this process import code by itself (``rl_jax.run.learners``,
``rl_jax.run.run_dir.recorded_env``).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt

from rl_jax.envs import Environment
from rl_jax.errors import PolicyError, parse_int
from rl_jax.run.best import BEST_DIR, load_part, policy_fields, with_policy_part
from rl_jax.run.checkpoint import Checkpointer, Tree
from rl_jax.run.learners import for_run, run_env
from rl_jax.run.metrics import METRICS_FILE, read_rows
from rl_jax.run.plan import make_plan
from rl_jax.run.run_dir import CHECKPOINT_DIR, identity_hash, read_run_record
from rl_jax.run.spec import RunSpec
from rl_jax.training.algorithm import (
    Algorithm,
    Config,
    PolicyFn,
    PolicyState,
    RecurrentPolicyFn,
    TrainState,
    hooks,
)
from rl_jax.training.episodes import batched_policy_state, reset_policy_state
from rl_jax.training.jax_setup import configure
from rl_jax.training.params import dataclass_from_dict

WHICH = ("best", "latest")


class LoadedPolicy:
    """One (config, seed) of a run, restored from its best policy or its latest checkpoint.

    Attributes: ``algorithm``, ``config``, ``env_id``, ``seed``, ``config_index``, ``which``
    (what was loaded: "best" falls back to "latest" for a run that kept no best policy), ``step``
    (the env step of that policy), ``eval_return`` (the run's eval of it, if known) and
    ``state`` (a train state whose policy fields are this run's; pass it to
    ``algorithm.policy(state, config)``). ``algorithm`` names the run's learner, which a run
    of the user's own learner needs (``rl_jax.run.learners.for_run``), and ``env`` its env,
    which a run on an env of the user's own module needs (``run_dir.recorded_env``).
    """

    def __init__(
        self,
        run_dir: Path,
        seed: int | None = None,
        config_index: int | None = None,
        which: str = "best",
        algorithm: str | Algorithm | None = None,
        env: str | None = None,
    ):
        if which not in WHICH:
            raise PolicyError(f"which must be one of {', '.join(WHICH)}, got {which!r}")
        self.run_dir = Path(run_dir)
        self.record = read_run_record(self.run_dir)
        identity = self.record["identity"]
        self.env_id: str = identity["env_id"]  # resolved in _restore, after the learner
        self._named_env = env
        self.seeds = [identity["base_seed"] + s for s in range(identity["seeds"])]
        self.which = which
        self.note: str | None = None
        self.eval_return: float | None = None
        self._named = algorithm
        self.config_index, self.seed = self._choose(seed, config_index, len(identity["hparams"]))
        self.algorithm, self.config, self.state, self.step = self._restore()

    def _choose(self, seed: int | None, config_index: int | None, configs: int) -> tuple[int, int]:
        """Defaults: the (config, seed) with the best eval return in metrics.jsonl (its final
        one for ``which="latest"``, its highest for ``"best"``)."""
        if config_index is not None and not 0 <= config_index < configs:
            raise PolicyError(f"--config {config_index} out of range: the run has {configs}")
        if seed is not None and seed not in self.seeds:
            raise PolicyError(f"--seed {seed} is not in this run (seeds {self.seeds})")
        best = _best_run(self.run_dir, config_index, seed, final_only=self.which == "latest")
        return (
            config_index if config_index is not None else best[0],
            seed if seed is not None else best[1] if best[1] is not None else self.seeds[0],
        )

    def _restore(self) -> tuple[Algorithm, Config, TrainState, int]:
        identity = self.record["identity"]
        algorithm = for_run(self.record, self.run_dir, self._named, how="algorithm=")
        # after the learner: a learner's own module may register the env it trains on
        self.env_id = run_env(self.record, self.run_dir, algorithm, self._named_env, "env=")
        config = dataclass_from_dict(algorithm.default_config(self.env_id), identity["config"])
        template = algorithm.default_hyperparams()
        hparams = tuple(dataclass_from_dict(template, h) for h in identity["hparams"])
        spec = RunSpec(
            algorithm,
            self.env_id,
            config,
            hparams,
            self.run_dir,
            seeds=identity["seeds"],
            base_seed=identity["base_seed"],
        )
        plan = make_plan(spec)
        # Saved before or after a resume under newer code (see start.checkpoint_accepts).
        hashes = {self.record["identity_hash"], identity_hash(spec.identity)}
        expect = {"identity_hash": frozenset(hashes)}
        run = (self.config_index, self.seeds.index(self.seed))
        if self.which == "best":
            fields = policy_fields(algorithm, plan.template)
            saved = load_part(self.run_dir / BEST_DIR, fields, plan.template, expect)
            if saved is not None and saved[1]["best_steps"][run[0]][run[1]] >= 0:
                part, meta = saved
                one = {name: _index(value, run) for name, value in part.items()}
                self.eval_return = meta["best_returns"][run[0]][run[1]]
                state = with_policy_part(plan.template, one)
                return algorithm, config, state, int(meta["best_steps"][run[0]][run[1]])
            self.which = "latest"
            self.note = "the run kept no best policy for this seed; using its latest checkpoint"
        with Checkpointer(self.run_dir / CHECKPOINT_DIR, read_only=True) as checkpointer:
            state, meta = checkpointer.restore(plan.template, expect=expect)
        selected = plan.program.select(state, *run)
        self.eval_return = _final_eval(self.run_dir, self.config_index, self.seed, meta["step"])
        return algorithm, config, selected, meta["step"]

    def env(self) -> Environment:
        """The env the policy acts in (``algorithm.make_env(config)``, by default the run's env)."""
        return hooks(self.algorithm).make_env(self.config)

    def act(self) -> PolicyFn:
        """The pure ``obs -> action`` JAX function (actions as the env of ``env()`` takes); for
        a recurrent learner ``(policy_state, obs) -> (action, policy_state)``."""
        return self.algorithm.policy(self.state, self.config)

    def initial_policy_state(self) -> PolicyState | None:
        """One env's policy state at an episode start; None for a feed-forward policy."""
        return hooks(self.algorithm).initial_policy_state(self.config)

    def describe(self) -> str:
        """One phrase naming the policy: best or latest, seed, config, step and eval return."""
        value = "" if self.eval_return is None else f", eval return {self.eval_return:.1f}"
        return (
            f"the {self.which} policy of seed {self.seed} "
            f"(config {self.config_index}, step {self.step:,}{value})"
        )


class Policy:
    """A plain ``obs -> action`` callable: numpy in, numpy out (one observation or a batch).

    Actions are what the original environment takes: env units for continuous actions, the
    index for discrete ones, and, for a continuous env a discrete learner drove through
    ``envs.DiscretizeActions``, the continuous value the index stands for. For an env with a
    legal-action mask, ``policy(obs, legal)`` chooses among the legal actions (bool ``[A]``, or
    ``[N, A]`` for a batch: the env's ``info["action_mask"]``).
    """

    def __init__(self, loaded: LoadedPolicy):
        self.loaded = loaded
        env = loaded.env()
        space = env.observation_space()
        self.observation_shape = tuple(space.shape)
        self._dtype = np.dtype(space.dtype)
        act = loaded.act()
        values = getattr(env, "action_values", None)
        table = None if values is None else jnp.asarray(values)

        act_legal: Callable[..., jax.Array] = act

        def batched(obs: jax.Array, legal: jax.Array | None) -> jax.Array:
            if legal is None:
                action = jax.vmap(act)(obs)
            else:
                action = jax.vmap(act_legal)(obs, legal)
            return action if table is None else table[action]

        self._act = jax.jit(batched)

    def __call__(self, obs: npt.ArrayLike, legal: npt.ArrayLike | None = None) -> np.ndarray:
        obs = np.asarray(obs, dtype=self._dtype)
        single = obs.shape == self.observation_shape
        if not single and obs.shape[1:] != self.observation_shape:
            raise ValueError(
                f"expected an observation of shape {self.observation_shape} or a batch "
                f"[N, *{self.observation_shape}], got shape {obs.shape}"
            )
        if legal is not None:
            legal = np.asarray(legal, dtype=bool)
            legal = legal[None] if single else legal
        action = np.asarray(self._act(obs[None] if single else obs, legal))
        return action[0] if single else action

    def __repr__(self) -> str:
        return f"<Policy: {self.loaded.describe()} of {self.loaded.run_dir}>"


class RecurrentPolicy:
    """The ``Policy`` of a recurrent learner: a callable that keeps the policy's state from
    one call to the next (numpy in, numpy out; one observation or a batch ``[N, ...]``, the
    batch's size kept until the next ``reset``).

    Call ``reset()`` at every episode start; for a batch of envs that end at different times,
    ``reset(done)`` gives a fresh state to the envs where ``done [N]`` is true only::

        policy = rl_jax.load_policy("runs/rppo_cartpole_novel")
        env = gymnasium.make("CartPole-v1")  # with the run's masking of the velocities
        obs, _ = env.reset(seed=0)
        policy.reset()
        for _ in range(500):
            obs, reward, terminated, truncated, _ = env.step(policy(obs))
            if terminated or truncated:
                obs, _ = env.reset()
                policy.reset()
    """

    def __init__(self, loaded: LoadedPolicy):
        self.loaded = loaded
        env = loaded.env()
        space = env.observation_space()
        self.observation_shape = tuple(space.shape)
        self._dtype = np.dtype(space.dtype)
        step = cast(RecurrentPolicyFn, loaded.act())
        initial = loaded.initial_policy_state()
        self._initial = initial
        values = getattr(env, "action_values", None)
        table = None if values is None else jnp.asarray(values)

        def batched(
            policy_state: PolicyState, obs: jax.Array, legal: jax.Array | None
        ) -> tuple[jax.Array, PolicyState]:
            if legal is None:
                action, policy_state = jax.vmap(step)(policy_state, obs)
            else:
                action, policy_state = jax.vmap(step)(policy_state, obs, legal)
            return (action if table is None else table[action]), policy_state

        self._act = jax.jit(batched)
        self._reset = jax.jit(lambda done, ps: reset_policy_state(done, ps, initial))
        self._state: PolicyState | None = None  # made at the first call after a reset

    def reset(self, done: npt.ArrayLike | None = None) -> None:
        """A fresh policy state: for every env, or (a batch) for those where ``done``."""
        if done is None or self._state is None:
            self._state = None
            return
        self._state = self._reset(jnp.asarray(np.asarray(done, dtype=bool)), self._state)

    def __call__(self, obs: npt.ArrayLike, legal: npt.ArrayLike | None = None) -> np.ndarray:
        obs = np.asarray(obs, dtype=self._dtype)
        single = obs.shape == self.observation_shape
        if not single and obs.shape[1:] != self.observation_shape:
            raise ValueError(
                f"expected an observation of shape {self.observation_shape} or a batch "
                f"[N, *{self.observation_shape}], got shape {obs.shape}"
            )
        batch = obs[None] if single else obs
        if self._state is None:
            self._state = batched_policy_state(self._initial, batch.shape[0])
        if legal is not None:
            legal = np.asarray(legal, dtype=bool)
            legal = legal[None] if single else legal
        action, self._state = self._act(self._state, batch, legal)
        action = np.asarray(action)
        return action[0] if single else action

    def __repr__(self) -> str:
        return f"<RecurrentPolicy: {self.loaded.describe()} of {self.loaded.run_dir}>"


class GamePolicy:
    """The policy of a learner that owns its env (``OptionalHooks.owns_env``: AlphaZero on a
    pgx game), for a person or a program to play against.

    ``move(state)``: the trained planner's move for a position, from the env's own state (a pgx
    ``State`` of the run's game, the side to move being ``state.current_player``): the
    learner's ``position_policy`` with a fixed key, so the same position gets the same move
    (AlphaZero: the search without Gumbel noise). ``policy(observation, legal_action_mask)``:
    the learner's ``policy``, for a caller that has only an observation (AlphaZero: the
    network's most likely legal move, no search). Both take one position and return an
    ``int``. Attributes: ``env_id`` (``"pgx/tic_tac_toe"``), ``game`` (the id's last part,
    ``"tic_tac_toe"``, as ``pgx.make`` takes it), ``num_simulations`` (the search's, None for
    a learner whose config has none), ``player`` (the pure ``(state, key) -> action`` behind
    ``move``, for ``rl_jax.envs.games.match.play_match``) and ``loaded`` (what was restored)."""

    def __init__(self, loaded: LoadedPolicy):
        self.loaded = loaded
        self.env_id = loaded.env_id
        self.game = loaded.env_id.rpartition("/")[2]
        simulations = getattr(loaded.config, "num_simulations", None)
        self.num_simulations = None if simulations is None else int(simulations)
        position = hooks(loaded.algorithm).position_policy(loaded.state, loaded.config)
        if position is None:
            raise PolicyError(
                f"{loaded.algorithm.name} owns the env {self.env_id} but has no "
                "position_policy(state, config) to move from its positions"
            )
        key = jax.random.key(0)
        self.player = position
        self._move = jax.jit(lambda state: position(state, key))
        self._act = jax.jit(loaded.act())

    def move(self, state: object) -> int:
        """The planner's move (an action index, legal) for the position ``state``, one env
        state of the run's game that is not over."""
        named = getattr(state, "env_id", self.game)
        if named != self.game:
            raise ValueError(f"this policy plays {self.game}, not {named}")
        return int(self._move(state))

    def __call__(self, observation: npt.ArrayLike, legal_action_mask: npt.ArrayLike) -> int:
        """The learner's ``policy`` (no search for AlphaZero) for one observation, among the
        actions where ``legal_action_mask`` is true."""
        obs = jnp.asarray(np.asarray(observation))
        legal = jnp.asarray(np.asarray(legal_action_mask, dtype=bool))
        return int(self._act(obs, legal))

    def __repr__(self) -> str:
        simulations = f", {self.num_simulations} simulations" if self.num_simulations else ""
        loaded = self.loaded
        return f"<GamePolicy {self.game}{simulations}: {loaded.describe()} of {loaded.run_dir}>"


def add_run_choice(parser: argparse.ArgumentParser, seed_help: str) -> None:
    """The ``--seed``, ``--config`` and ``--algo`` options of the commands that load a run's
    policies."""
    parser.add_argument(
        "--algo",
        default=None,
        metavar="LEARNER",
        help="the run's learner, when it is one of your own (MODULE:NAME or "
        "path/to/file.py:NAME, as it was trained with): a run never imports one by itself",
    )

    parser.add_argument(
        "--env",
        default=None,
        metavar="ENV",
        help="the run's env, when it comes from a module of your own (MODULE:ID, as it was "
        "trained with): a run never imports one by itself",
    )
    parser.add_argument("--seed", type=parse_int, default=None, help=seed_help)
    parser.add_argument(
        "--config",
        type=parse_int,
        default=None,
        dest="config_index",
        help="config index of a sweep (default: the best)",
    )


def command_line_learner(run_dir: Path, named: str | None) -> Algorithm:
    """The learner a command that opens ``run_dir`` uses (``--algo``, or the run's built-in
    one); its errors say to give ``--algo``."""
    return for_run(read_run_record(run_dir), run_dir, named, how="--algo")


def command_line_env(run_dir: Path, named: str | None, learner: Algorithm | None = None) -> str:
    """The env id a command that opens ``run_dir`` uses (``--env``, or the run's own when it
    needs no import, or when ``learner``, ``command_line_learner``'s, owns it); its errors say
    to give ``--env``."""
    return run_env(read_run_record(run_dir), run_dir, learner, named)


def load_policy(
    run_dir: str | Path,
    seed: int | None = None,
    which: str = "best",
    config: int | None = None,
    algorithm: str | Algorithm | None = None,
    env: str | None = None,
) -> Policy | RecurrentPolicy | GamePolicy:
    """The trained policy of a run as a numpy ``obs -> action`` callable (a ``RecurrentPolicy``,
    which keeps its state between calls and has ``reset()``, for a recurrent learner; a
    ``GamePolicy``, with ``move(state)`` for a position, for a learner that owns its env).

    ``seed``: which seed (default: the one with the best eval return); ``which``: "best" (the
    policy of that seed's best evaluation) or "latest" (its latest checkpoint); ``config``: the
    config index of a sweep (default: the best); ``algorithm``: the run's learner, when it is
    one of your own (as ``--algo`` names it, or the object); ``env``: the run's env, when it
    comes from a module of your own (``MODULE:ID``, as ``--env`` names it).
    """
    configure()
    loaded = LoadedPolicy(Path(run_dir), seed, config, which, algorithm, env)
    if hooks(loaded.algorithm).owns_env(loaded.env_id):
        return GamePolicy(loaded)
    if loaded.initial_policy_state() is not None:
        return RecurrentPolicy(loaded)
    return Policy(loaded)


def _index(tree: Tree, run: tuple[int, int]) -> Tree:
    """One run's leaves of the small policy part, indexed on the host: not a program per leaf."""

    def one(leaf: jax.Array | np.ndarray) -> jax.Array:
        key = isinstance(leaf, jax.Array) and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key)
        return leaf[run] if key else jnp.asarray(np.asarray(leaf)[run])

    return jax.tree.map(one, tree)


def _rows(run_dir: Path) -> list[dict[str, Any]]:
    return [row for row in read_rows(run_dir / METRICS_FILE) if row.get("eval_return") is not None]


def _best_run(
    run_dir: Path, config_index: int | None, seed: int | None, final_only: bool
) -> tuple[int, int | None]:
    rows = [
        row
        for row in _rows(run_dir)
        if (config_index is None or row.get("config", 0) == config_index)
        and (seed is None or row["seed"] == seed)
    ]
    if final_only and rows:
        last = max(row["step"] for row in rows)
        rows = [row for row in rows if row["step"] == last]
    if not rows:
        return (config_index or 0), seed
    best = max(rows, key=lambda row: row["eval_return"])
    return best.get("config", 0), best["seed"]


def _final_eval(run_dir: Path, config_index: int, seed: int, step: int) -> float | None:
    for row in _rows(run_dir):
        if row["step"] == step and row["seed"] == seed and row.get("config", 0) == config_index:
            return float(row["eval_return"])
    return None
