"""``python -m rl_jax.run.evaluate RUN_DIR``: each seed's policies on many fresh episodes.

A run evaluates its policy on ``num_eval_envs`` episodes (10 by default) at every chunk, and
keeps the policy of each seed's best evaluation in ``best/``: the best of many small samples, so
its recorded return is optimistic. This evaluates the kept policies again, on ``--episodes`` new
episodes each (100 by default, all stepped together in one compiled loop, with env keys no
training evaluation used), and prints per seed the run's own figure beside the mean, spread and
range of the new episodes. ``--latest`` adds each seed's latest checkpoint. A run of a learner
of your own needs ``--algo`` naming it again, as it was trained with.

``--gymnasium`` plays the same policies in gymnasium's own env instead (``gymnasium.make`` of the
run's env: ``HalfCheetah-v5`` for ``rl_jax/HalfCheetah-v5``, ``ID`` for ``gymnasium:ID``, with
the run's env keywords), stepped on the host one episode at a time, seeded ``KEY + episode``:
evidence, from code we did not write, that the policy learned the task and not a quirk of our
copy of the env. A velocity-masked id (``rl_jax/CartPoleNoVel-v1``, ``rl_jax/Hopper-P-v5``, ...:
envs/memory/masked.py) plays in gymnasium's base env under the same mask (``gymnasium_twin``),
a recurrent policy reset at every episode.

    python -m rl_jax.run.evaluate runs/results/dqn-cartpole-pixels --episodes 100 --latest
    python -m rl_jax.run.evaluate runs/ppo_hopper --gymnasium --episodes 20
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import gymnasium
import jax
import numpy as np

from rl_jax import envs
from rl_jax.envs.memory import masked
from rl_jax.errors import OneLineParser, UsageError, exit_now, guard, positive_int
from rl_jax.run.api import evaluate_policy as returns_of
from rl_jax.run.policy import (
    LoadedPolicy,
    Policy,
    RecurrentPolicy,
    add_run_choice,
    command_line_env,
    command_line_learner,
)
from rl_jax.training.algorithm import Algorithm, TakesEnvKeywords
from rl_jax.training.jax_setup import configure

KEY = 20_251_125  # evaluation episodes' key: none of a run's own evaluations draws it
# Keywords of our envs' constructors that gymnasium's do not take: how we simulate, not what.
OWN_KEYWORDS = frozenset({"backend", "fidelity", "nthread"})


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """One policy's returns on fresh episodes, beside the run's own evaluation of it."""

    seed: int
    which: str  # "best" or "latest" (what was loaded)
    step: int  # env step of the policy
    run_eval: float | None  # the run's own evaluation of it
    returns: np.ndarray  # [episodes]
    env: str = ""  # where the episodes were played: "" for the run's env, else gymnasium's twin


def evaluate_policy(loaded: LoadedPolicy, episodes: int, key: int = KEY) -> np.ndarray:
    """Returns ``[episodes]`` of ``loaded``'s deterministic policy in the run's env."""
    initial = loaded.initial_policy_state()
    return returns_of(loaded.env(), loaded.act(), jax.random.key(key), episodes, initial)


def gymnasium_id(env_id: str) -> str:
    """gymnasium's id of a run's env: ``ID`` of ``gymnasium:ID``; ``NAME`` of ``rl_jax/NAME``
    where gymnasium registers ``NAME`` (the MuJoCo v5 suite, CartPole, Pendulum)."""
    if env_id.startswith("gymnasium:"):
        return env_id.split(":", 1)[1]
    name = env_id.split(":")[-1].removeprefix("rl_jax/")
    if name == env_id or name not in gymnasium.registry:
        raise UsageError(f"{env_id} has no twin registered in gymnasium to replay its policies in")
    return name


def gymnasium_returns(
    policy: Callable[[np.ndarray], np.ndarray],
    env_id: str,
    episodes: int,
    keywords: dict[str, Any] | None = None,  # gymnasium.make's, values of any type
    key: int = KEY,
) -> np.ndarray:
    """Returns ``[episodes]`` of ``policy`` in ``gymnasium.make(env_id, **keywords)``, episode
    ``i`` reset with seed ``key + i`` and played to termination or truncation."""
    env = gymnasium.make(env_id, **(keywords or {}))
    try:
        return _play(env, policy, episodes, key)
    finally:
        env.close()


def _play(
    env: gymnasium.Env, policy: Callable[[np.ndarray], np.ndarray], episodes: int, key: int
) -> np.ndarray:
    """``gymnasium_returns`` on an env already made."""
    returns = np.zeros(episodes)
    for episode in range(episodes):
        obs, _ = env.reset(seed=key + episode)
        if isinstance(policy, RecurrentPolicy):
            policy.reset()
        done = False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(policy(obs))
            returns[episode] += float(reward)
            done = bool(terminated or truncated)
    return returns


def gymnasium_twin(env_id: str, keywords: dict[str, object]) -> tuple[str, gymnasium.Env]:
    """gymnasium's own env for a run's ``env_id``, made with ``keywords``, and its name:
    ``gymnasium.make`` of ``gymnasium_id``, or for a masked id (envs/memory/masked.py) its base
    env under the same mask (``masked.gymnasium_twin``), named ``BASE masked as ID``."""
    name = env_id.split(":")[-1]
    if name in masked.GYMNASIUM_BASES:
        twin = masked.gymnasium_twin(name, **cast(dict[str, Any], keywords))
        return f"{masked.GYMNASIUM_BASES[name]} masked as {name}", twin
    twin_id = gymnasium_id(env_id)
    return twin_id, gymnasium.make(twin_id, **cast(dict[str, Any], keywords))


def _in_gymnasium(loaded: LoadedPolicy, episodes: int) -> tuple[str, np.ndarray]:
    """``loaded``'s policy in gymnasium's twin of the run's env: its name and the returns."""
    config = loaded.config
    keywords = envs.parse_keywords(
        config.env_kwargs if isinstance(config, TakesEnvKeywords) else ""
    )
    keywords = {name: value for name, value in keywords.items() if name not in OWN_KEYWORDS}
    policy = (
        RecurrentPolicy(loaded) if loaded.initial_policy_state() is not None else Policy(loaded)
    )
    env_id, env = gymnasium_twin(loaded.env_id, keywords)
    try:
        shape = tuple(env.observation_space.shape or ())
        if shape != policy.observation_shape:
            raise UsageError(
                f"gymnasium's {env_id} observes shape {shape}, the run's policy "
                f"{policy.observation_shape}: its episodes cannot be replayed there"
            )
        return env_id, _play(env, policy, episodes, KEY)
    finally:
        env.close()


def evaluate_run(
    run_dir: Path,
    episodes: int = 100,
    seeds: list[int] | None = None,
    config_index: int | None = None,
    latest: bool = False,
    algorithm: str | Algorithm | None = None,
    gymnasium: bool = False,
    env: str | None = None,
) -> list[Evaluation]:
    """Every seed's best policy (and its latest, with ``latest``) on ``episodes`` episodes of
    the run's env, or with ``gymnasium`` of gymnasium's own; ``algorithm`` names the run's
    learner when it is not built in, ``env`` its env when it comes from a module of the
    user's own."""
    first = LoadedPolicy(run_dir, None, config_index, "latest", algorithm, env)
    evaluations = []
    for seed in first.seeds if seeds is None else seeds:
        for which in ("best", "latest") if latest else ("best",):
            loaded = LoadedPolicy(
                run_dir, seed, first.config_index, which, first.algorithm, first.env_id
            )
            env, returns = (
                _in_gymnasium(loaded, episodes)
                if gymnasium
                else ("", evaluate_policy(loaded, episodes))
            )
            evaluations.append(
                Evaluation(seed, loaded.which, loaded.step, loaded.eval_return, returns, env)
            )
    return evaluations


def table(evaluations: list[Evaluation]) -> str:
    """The evaluations as a text table: per policy its step, the run's eval and the fresh
    episodes' mean, std, min and max.
    """
    episodes = len(evaluations[0].returns)
    where = evaluations[0].env and f" of gymnasium's {evaluations[0].env}"
    lines = [
        f"each policy on {episodes} fresh episodes{where}",
        "",
        "  seed  policy        step   run's eval      mean      std       min       max",
        "  ----  ------  ----------   ----------  --------  -------  --------  --------",
    ]
    for e in evaluations:
        run_eval = "-" if e.run_eval is None else f"{e.run_eval:.1f}"
        r = e.returns
        lines.append(
            f"  {e.seed:4d}  {e.which:6s}  {e.step:10,d}   {run_eval:>10s}  {r.mean():8.1f}  "
            f"{r.std():7.1f}  {r.min():8.1f}  {r.max():8.1f}"
        )
    lines.append("")
    for which in dict.fromkeys(e.which for e in evaluations):
        means = [e.returns.mean() for e in evaluations if e.which == which]
        lines.append(f"  mean over seeds, {which}: {np.mean(means):.1f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None, prog: str = "python -m rl_jax.run.evaluate") -> int:
    """``python -m rl_jax.run.evaluate RUN_DIR``: run each seed's best (and with ``--latest``
    latest) policy on fresh episodes and print the table. Returns the exit status. ``prog`` is
    the command named in ``--help`` and errors (``rl-jax evaluate``).
    """
    parser = OneLineParser(prog=prog, description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path, help="a run directory (holds config.json)")
    parser.add_argument(
        "--episodes", type=positive_int, default=100, help="episodes per policy (default: 100)"
    )
    add_run_choice(parser, "only this seed (default: every seed)")
    parser.add_argument(
        "--latest", action="store_true", help="also each seed's latest checkpoint's policy"
    )
    parser.add_argument(
        "--gymnasium",
        action="store_true",
        help="play the episodes in gymnasium's own env (HalfCheetah-v5 for "
        "rl_jax/HalfCheetah-v5; CartPole-v1 with the velocities zeroed for "
        "rl_jax/CartPoleNoVel-v1), stepped on the host",
    )
    args = parser.parse_args(argv)

    def run() -> int:
        configure()
        seeds = None if args.seed is None else [args.seed]
        learner = command_line_learner(args.run_dir, args.algo)  # first: it may register the env
        env_id = command_line_env(args.run_dir, args.env)
        evaluations = evaluate_run(
            args.run_dir,
            args.episodes,
            seeds,
            args.config_index,
            args.latest,
            learner,
            args.gymnasium,
            env_id,
        )
        print(table(evaluations))
        return 0

    return guard(run)


if __name__ == "__main__":
    # Run the imported module's main, not this __main__ copy, so that its exception classes are
    # the ones the guard knows.
    from rl_jax.run.evaluate import main as module_main

    exit_now(module_main())
