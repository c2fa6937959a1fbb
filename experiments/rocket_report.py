"""Learned rocket policies next to the controllers control theory gives for the same task.

    python experiments/rocket_report.py RUN_DIR [RUN_DIR ...] [--out DIR] [--env ID]
                                        [--start X V] [--latest] [--steps N] [--tolerance T]

Users asked the rocket to come to rest at the origin "like a classical controller". This tool
shows how close a run gets: every seed of every run (TD3, DQN, any learner on the rocket),
rolled from one exact start (default ``(1, 0)``) through the env's own step, beside the
time-optimal bang-bang feedback (at rest at t* = 2 s from ``(1, 0)``) and a saturated LQR law
(``envs.classic.rocket_control``). It writes to ``--out`` (default: the first run directory):

* ``rocket_comparison.png``: x(t) and v(t) of every policy, on the full scale and zoomed to the
  goal box ``|x|, |v| <= tolerance`` (shaded);
* ``rocket_comparison.md`` (also printed): per controller and seed, the step from which the
  state stays inside the box, whether it is still there at the last step, the env's episode
  return, the final (x, v) and what ended the env's own episode
  (``envs.classic.rocket_comparison`` draws both).

Each seed's best evaluated policy is used (``--latest``: its latest checkpoint's). DQN's index
actions come back from ``rl_jax.load_policy`` as the thrust they stand for ({-1, 0, +1} with 3
bins). The rollout ignores termination, so staying in the box is measured even on
``rl_jax/Rocket-v0``, whose episode ends at its 1e-8 goal; the return stops where the env's
episode would. ``--env`` picks the env to roll in (default: the runs' env); the rocket variants
share their dynamics and differ in reward. Bad input (no run, a run on another env, a start
outside the track) ends with one line on stderr and status 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rl_jax import envs
from rl_jax.envs.classic import rocket_control
from rl_jax.envs.classic.rocket import Rocket
from rl_jax.envs.classic.rocket_comparison import (
    Entry,
    Settings,
    analytic_entries,
    entry,
    headline,
    markdown_table,
    write_report,
)
from rl_jax.errors import OneLineParser, UsageError, exit_now, guard, parse_float, positive_int
from rl_jax.run.policy import load_policy
from rl_jax.run.run_dir import read_run_record, recorded_env
from rl_jax.training.jax_setup import configure

DEFAULT_ENV = "rl_jax/Rocket-v0"


class ReportError(UsageError):
    """Input the comparison cannot use (a run on another env, a start off the track)."""


# ---- what to compare ---------------------------------------------------------------------------


def is_rocket_env(env_id: str) -> bool:
    """Whether ``env_id`` is registered as the rocket or a variant of it."""

    builder = envs.core.registry.factory(env_id)
    return isinstance(builder, type) and issubclass(builder, Rocket)


def run_env_id(run_dir: Path) -> str:
    """The env a run trained on; ``ReportError`` unless it is a rocket."""

    identity = read_run_record(run_dir)["identity"]
    # resolved from the registry alone: a run's record never makes this report import code
    env_id = recorded_env(identity["env_id"], run_dir)
    if not is_rocket_env(env_id):
        raise ReportError(
            f"{run_dir} is a {identity['algorithm']} run on {identity['env_id']}, not on the "
            "rocket: this report compares rocket policies with the rocket's analytic controllers"
        )
    return env_id


def choose_env(run_dirs: list[Path], env_id: str | None) -> str:
    """``env_id`` if given (it must be a rocket), else the env all runs share."""

    if env_id is not None:  # named first: a rocket of the user's own module is imported here
        env_id = envs.core.registry.resolve_id(env_id)
        if not is_rocket_env(env_id):
            raise ReportError(f"--env {env_id} is not a rocket env")
    run_envs = {run_env_id(run_dir) for run_dir in run_dirs}
    if env_id is not None:
        return env_id
    if len(run_envs) > 1:
        raise ReportError(
            f"the runs trained on different envs ({', '.join(sorted(run_envs))}): choose the "
            "one to roll them in with --env (the rocket variants share their dynamics)"
        )
    return run_envs.pop() if run_envs else DEFAULT_ENV


def check_start(start: tuple[float, float], env_id: str) -> None:
    """A start the env would end at once (off the track) compares nothing."""

    bound = float(envs.make(env_id).default_params.bound)
    if max(abs(start[0]), abs(start[1])) > bound:
        raise ReportError(f"--start {start[0]:g} {start[1]:g} is outside |x|, |v| <= {bound:g}")


# ---- rollouts -----------------------------------------------------------------------------------


def run_entries(run_dir: Path, which: str, settings: Settings) -> list[Entry]:
    """Every (config, seed) policy of ``run_dir``, rolled out as ``settings`` say."""

    identity = read_run_record(run_dir)["identity"]
    seeds = [identity["base_seed"] + index for index in range(identity["seeds"])]
    configs = len(identity["hparams"])
    # A policy reads the observation of the variant it trained on (RocketSettle's adds zoomed
    # features), whichever variant's dynamics and reward it is rolled in.
    own_env = envs.make(identity["env_id"])

    def own_observation(obs: np.ndarray) -> np.ndarray:
        return np.asarray(own_env.state_from_vector(np.asarray(obs[:2], np.float32))[1])

    entries = []
    for config in range(configs):
        name = f"{identity['algorithm']} ({Path(run_dir).name})"
        name += f" config {config}" if configs > 1 else ""
        for seed in seeds:
            policy = load_policy(run_dir, seed, which, config)
            described = f"{policy.loaded.which}, step {policy.loaded.step:,}"
            controller = lambda obs, policy=policy: policy(own_observation(obs))  # noqa: E731
            entries.append(entry(name, seed, described, controller, settings))
    return entries


def compare(
    run_dirs: list[Path],
    which: str = "best",
    env_id: str | None = None,
    start: tuple[float, float] = (1.0, 0.0),
    steps: int | None = None,
    tolerance: float = rocket_control.TOLERANCE,
) -> tuple[list[Entry], Settings]:
    """Analytic controllers first, then every seed of every run; and the settings used."""

    env_id = choose_env(list(run_dirs), env_id)
    check_start(start, env_id)
    env = envs.make(env_id)
    settings = Settings(
        env_id=env_id,
        start=(float(start[0]), float(start[1])),
        steps=env.max_episode_steps if steps is None else int(steps),
        tolerance=float(tolerance),
        dt=float(env.default_params.dt),
    )
    entries = analytic_entries(settings)
    for run_dir in run_dirs:
        entries += run_entries(Path(run_dir), which, settings)
    return entries, settings


# ---- command line -------------------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="python experiments/rocket_report.py", description=__doc__.split("\n")[0]
    )
    parser.add_argument(
        "run_dirs", type=Path, nargs="*", metavar="RUN_DIR", help="run directories of rocket runs"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="directory for the plot and table (default: the first RUN_DIR, or . without one)",
    )
    parser.add_argument(
        "--env",
        default=None,
        metavar="ID",
        help="env to roll in (default: the runs' env, rl_jax/Rocket-v0 without runs)",
    )
    parser.add_argument(
        "--start",
        type=parse_float,
        nargs=2,
        default=(1.0, 0.0),
        metavar=("X", "V"),
        help="exact start state (default: 1 0)",
    )
    parser.add_argument(
        "--latest",
        action="store_true",
        help="each seed's latest policy (default: its best evaluated one)",
    )
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        metavar="N",
        help="steps to roll (default: the env's episode limit, 500)",
    )
    parser.add_argument(
        "--tolerance",
        type=parse_float,
        default=rocket_control.TOLERANCE,
        metavar="T",
        help="half-width of the goal box in x and v (default: 0.01)",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)

    def report() -> int:
        configure()
        if args.tolerance <= 0:
            raise ReportError(f"--tolerance must be > 0, got {args.tolerance:g}")
        which = "latest" if args.latest else "best"
        entries, settings = compare(
            args.run_dirs, which, args.env, tuple(args.start), args.steps, args.tolerance
        )
        out = args.out or (args.run_dirs[0] if args.run_dirs else Path("."))
        try:
            plot_path, table_path = write_report(entries, settings, out)
        except OSError as error:
            reason = error.strerror or error
            raise ReportError(f"cannot write the report to {out}: {reason}") from None
        print(headline(settings), "", markdown_table(entries, settings), "", sep="\n")
        print(f"wrote {plot_path} and {table_path}")
        return 0

    return guard(report)


if __name__ == "__main__":
    exit_now(main())
