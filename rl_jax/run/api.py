"""Training and inspecting runs from Python (a notebook, a script), with the CLI's run contract.

    import rl_jax

    run = rl_jax.train("td3", "rl_jax/Pendulum-v1", seeds=5, total_steps=20_000)
    run.results            # the final table: per seed final and best eval, mean, 95% CI
    run.plot()             # curves.png (shown inline in a notebook)
    run.evaluate(10)       # fresh evaluation of every seed's policy: {seed: mean return}
    run.save_gif("p.gif")  # the best seed's best policy
    act = run.policy(0)    # numpy obs -> numpy action

    run = rl_jax.open_run("runs/Pendulum-v1__td3__...")   # the same object for an existing run

A learner of your own goes where a name goes: ``rl_jax.train("my_learner.py:learner", ...)``
or the object itself; its runs are opened with it named again (``open_run(dir, algorithm=...)``,
``resume(dir, algorithm=...)``): a run directory never makes this process import code.

``train`` writes the same run directory as the experiment scripts (config.json, metrics.jsonl,
checkpoints/, best/, curves.png, results.txt), so ``python -m rl_jax.run.render`` and ``--resume``
work on it. Progress is one line per ``log_interval`` seconds when the output is not a terminal
(a notebook cell), never a line per chunk.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import jax
import numpy as np

from rl_jax import envs
from rl_jax.errors import RunError
from rl_jax.run import command, learners, plots, recipe_choice
from rl_jax.run import distributed as joining
from rl_jax.run.learners import for_run
from rl_jax.run.metrics import METRICS_FILE, read_rows
from rl_jax.run.policy import LoadedPolicy, load_policy
from rl_jax.run.render import write_gif
from rl_jax.run.run_dir import CURVES_FILE, read_run_record
from rl_jax.run.runner import run
from rl_jax.run.spec import RunSpec
from rl_jax.training.algorithm import Algorithm, PolicyFn, RecurrentPolicyFn
from rl_jax.training.episodes import episode_returns, recurrent_episode_returns
from rl_jax.training.jax_setup import configure_jax, wanted_cpu_devices
from rl_jax.training.params import dataclass_from_dict


class Run:
    """A run directory, trained or opened: its results, curves, policies and GIFs.
    ``algorithm``: the run's learner as the user names it (None: the run's built-in one), kept
    as the attribute ``learner``; ``env``: the run's env named again where it is one of the
    user's own (``"my_module:MyEnv-v0"``)."""

    def __init__(
        self,
        run_dir: str | Path,
        results: list[plots.FinalResult] | None = None,
        algorithm: str | Algorithm | None = None,
        env: str | None = None,
    ):
        self.run_dir = Path(run_dir)
        self.record = read_run_record(self.run_dir)
        identity = self.record["identity"]
        # named by the user, resolved and checked once (its module may register the run's env)
        self.learner: Algorithm | None = (
            None
            if algorithm is None
            else for_run(self.record, self.run_dir, algorithm, "algorithm=")
        )
        self.algorithm: str = identity["algorithm"]
        self.env_id: str = learners.run_env(self.record, self.run_dir, self.learner, env, "env=")
        self.seeds: list[int] = [identity["base_seed"] + s for s in range(identity["seeds"])]
        self._results = results

    @property
    def results(self) -> plots.FinalResult | list[plots.FinalResult]:
        """The final results: a ``plots.FinalResult`` (per seed ``returns``, ``best``, ``mean``,
        ``ci_low``/``ci_high``, ``iqm``), or a list of them for a sweep. Printing gives the
        table."""
        if self._results is None:
            self._results = _results_from_metrics(self.run_dir, self.record)
        return self._results[0] if len(self._results) == 1 else self._results

    @property
    def table(self) -> str:
        """The final table as text (what the scripts print at the end)."""
        results = self.results
        if isinstance(results, list):
            return plots.sweep_table(results)
        return plots.results_table(results)

    def policy(self, seed: int | None = None, which: str = "best", config: int | None = None):
        """The numpy ``obs -> action`` callable of ``seed`` (default: the best seed)."""
        return load_policy(self.run_dir, seed, which, config, self.learner, self.env_id)

    def evaluate(self, episodes: int = 10, which: str = "best", key: int = 0) -> dict[int, float]:
        """Mean undiscounted return of ``episodes`` fresh episodes of each seed's deterministic
        policy (in the env the run trained on, episodes vmapped in one compiled call)."""
        returns = {}
        for seed in self.seeds:
            loaded = LoadedPolicy(self.run_dir, seed, None, which, self.learner, self.env_id)
            initial = loaded.initial_policy_state()
            totals = evaluate_policy(
                loaded.env(), loaded.act(), jax.random.key(key), episodes, initial
            )
            returns[seed] = float(np.mean(totals))
        return returns

    def save_gif(
        self,
        path: str | Path | None = None,
        seed: int | None = None,
        which: str = "best",
        episodes: int = 1,
    ) -> Path:
        """A GIF of the policy (default: the best seed's best) at ``path``, else at
        ``RUN_DIR/policy.gif``, or ``policy-2.gif``, ... where that exists: never over a GIF
        already there unless ``path`` names it. For a board-game run (AlphaZero on
        ``pgx/tic_tac_toe`` or ``pgx/connect_four``) each episode is one game of the trained
        search against the run's evaluation opponent (``rl_jax.run.render_game``)."""
        return write_gif(
            self.run_dir, seed, episodes, path, which=which, algorithm=self.learner, env=self.env_id
        )

    def plot(self) -> Any:
        """curves.png (redrawn from metrics.jsonl): an inline image in IPython, else its path."""
        path = self.run_dir / CURVES_FILE
        curves = plots.curves_from_rows(
            read_rows(self.run_dir / METRICS_FILE), tuple(self.record.get("grid_fields", ()))
        )
        plots.plot_curves(curves, path, title=f"{self.algorithm} on {self.env_id}")
        try:
            from IPython.display import Image  # heavy and optional: only in a notebook
        except ImportError:
            return path
        return Image(filename=str(path))

    def __repr__(self) -> str:
        return f"<Run {self.algorithm} on {self.env_id}, {len(self.seeds)} seeds: {self.run_dir}>"


def train(
    algorithm: str | Algorithm,
    env_id: str,
    seeds: int = 1,
    total_steps: int | None = None,
    out: str | Path | None = None,
    config: dict[str, Any] | None = None,
    hparams: dict[str, Any] | None = None,
    log_interval: float = 30.0,
    quiet: bool = False,
    recipe: str | None = None,
    layout: str = "auto",
    wandb: bool = False,
    distributed: bool = False,
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
) -> Run:
    """Train ``algorithm`` ("td3", "ddpg", "td7", "crossq", "sac", "ppo", "dqn", "reinforce"; a
    learner of your own as "my_package.my_module:learner" or "path/to/file.py:learner", or the
    learner object) on ``env_id`` with every seed in one compiled program, into a run directory
    (default ``runs/<env>__<algo>__<time>/``).

    The settings are the learner's ``recipe`` for the env (None: its default; the names are
    those of ``--recipe`` in the scripts), then ``config`` / ``hparams``, which override fields
    by name (as the scripts' flags do); ``total_steps`` defaults to the recipe's budget, else
    100,000 env steps per seed. ``wandb=True`` also logs every seed to Weights & Biases, as
    ``--wandb`` does (``rl_jax.run.tracking``). ``layout`` lays out seeds that do not divide
    over the devices, as ``--layout`` does: "pad", "split" or "auto".

    Devices are the CLI's: one JAX device per CPU core (``RL_JAX_CPU_DEVICES`` overrides the
    count), over which seeds are sharded. That takes effect only where JAX has not started yet
    in this process; a notebook that ran JAX before gets one line saying how many devices the
    run uses and why.

    Over several processes (``docs/cluster.md``), every process calls ``train`` alike, before
    any other JAX work: ``distributed=True`` under SLURM or Open MPI, or ``coordinator="HOST:PORT",
    num_processes=N, process_id=I`` anywhere; process 0 writes the run directory and prints.
    """
    join = joining.Options(distributed, coordinator, num_processes, process_id)
    cluster = joining.resolve(join)
    _use_every_core(quiet)
    if cluster is not None:
        try:
            joining.initialize(cluster, join.timeout)
        except RuntimeError as error:
            raise RunError(f"cannot join the other processes: {error}") from None
    learner = learners.resolve(algorithm)
    chosen = recipe_choice.recipe_named(learner, env_id, recipe or None)
    base_config, base_hparams = recipe_choice.recipe_settings(learner, env_id, chosen)
    total_steps = total_steps or chosen.total_steps
    chosen_config = command.replace_fields(base_config, dict(config or {}), "config")
    chosen_hparams = command.replace_fields(base_hparams, dict(hparams or {}), "hyperparameters")
    command.validate_settings(learner, chosen_config, [chosen_hparams])
    command.check_env_fits(learner, chosen_config, chosen_hparams)
    run_dir = Path(out) if out is not None else command.default_run_dir(env_id, learner.name)
    named = algorithm if isinstance(algorithm, str) else learner.name
    env_hint = f", env={env_id!r}" if envs.core.registry.names_a_module(env_id) else ""
    spec = RunSpec(
        algorithm=learner,
        env_id=env_id,
        config=chosen_config,
        hparams=(chosen_hparams,),
        out=run_dir,
        seeds=seeds,
        total_steps=100_000 if total_steps is None else int(total_steps),
        log_interval=log_interval,
        layout=layout,
        wandb=wandb,
        command=f"rl_jax.train({named!r}, {env_id!r}, seeds={seeds}, ...)",
        resume_command=f"rl_jax.resume({str(run_dir)!r}{learners.python_hint(learner)}{env_hint})",
    )
    result = run(spec, notify=(lambda message: None) if quiet else print)
    return Run(result.run_dir, result.results or None, learner)


def resume(
    run_dir: str | Path,
    total_steps: int | None = None,
    quiet: bool = False,
    algorithm: str | Algorithm | None = None,
    wandb: bool = False,
    env: str | None = None,
) -> Run:
    """Continue a run (from the scripts or ``train``) from its latest checkpoint.
    ``algorithm``: the run's learner, when it is one of your own (named as for ``train``);
    ``wandb``: log to Weights & Biases, continuing the W&B runs of the run's earlier starts;
    ``env``: the run's env, when it comes from a module of your own (``MODULE:ID``)."""
    _use_every_core(quiet)
    run_dir = Path(run_dir)
    record = read_run_record(run_dir)
    identity = record["identity"]
    learner = for_run(record, run_dir, algorithm, how="algorithm=")  # may register the env
    env_id = learners.run_env(record, run_dir, learner, env, how="env=")
    config = dataclass_from_dict(learner.default_config(env_id), identity["config"])
    template = learner.default_hyperparams()
    spec = RunSpec(
        algorithm=learner,
        env_id=env_id,
        config=config,
        hparams=tuple(dataclass_from_dict(template, h) for h in identity["hparams"]),
        out=run_dir,
        seeds=identity["seeds"],
        base_seed=identity["base_seed"],
        total_steps=record.get("total_steps", 0) if total_steps is None else int(total_steps),
        resume=True,
        grid_fields=tuple(record.get("grid_fields", ())),
        wandb=wandb,
    )
    result = run(spec, notify=(lambda message: None) if quiet else print)
    return Run(result.run_dir, result.results or None, learner, env_id)


def open_run(
    run_dir: str | Path, algorithm: str | Algorithm | None = None, env: str | None = None
) -> Run:
    """The ``Run`` of an existing run directory; ``algorithm`` names its learner when it is one
    of your own, and ``env`` its env when it comes from a module of your own (``MODULE:ID``):
    a run directory is data, and opening one imports neither by itself."""
    return Run(run_dir, algorithm=algorithm, env=env)


def evaluate_policy(
    env: envs.Environment,
    act: PolicyFn | RecurrentPolicyFn,
    key: jax.Array,
    episodes: int,
    initial_policy_state: object | None = None,
) -> np.ndarray:
    """``[episodes]`` undiscounted returns of ``act`` (one observation -> its action) in
    ``env``, all episodes vmapped in one jitted while loop (each stops at termination or the
    env's step limit): ``rl_jax.training.episodes.episode_returns``. With
    ``initial_policy_state`` (a recurrent policy's, one env's), ``act`` maps ``(policy_state,
    obs) -> (action, policy_state)`` and each episode starts from that state."""
    if initial_policy_state is not None:
        initial, recurrent = initial_policy_state, cast(RecurrentPolicyFn, act)
        run_all = jax.jit(
            lambda key: recurrent_episode_returns(jax.vmap(recurrent), initial, env, key, episodes)
        )
        return np.asarray(run_all(key))
    feed_forward = cast(PolicyFn, act)
    run_all = jax.jit(lambda key: episode_returns(jax.vmap(feed_forward), env, key, episodes))
    return np.asarray(run_all(key))


def _use_every_core(quiet: bool) -> None:
    """The CLI's device layout (``jax_setup.configure_jax``: a JAX device per CPU core), and a
    line when JAX started earlier in this process with fewer devices than that."""
    configure_jax()
    wanted = wanted_cpu_devices()
    if quiet or jax.default_backend() != "cpu" or jax.local_device_count() >= wanted:
        return
    print(
        f"note: JAX started in this process before rl_jax with {jax.local_device_count()} CPU "
        f"device(s), so the run shards its seeds over those, not over all {wanted} cores; "
        "call rl_jax first (or set XLA_FLAGS=--xla_force_host_platform_device_count=N)"
    )


def _results_from_metrics(run_dir: Path, record: dict[str, Any]) -> list[plots.FinalResult]:

    rows = read_rows(run_dir / METRICS_FILE)
    curves = plots.curves_from_rows(rows, tuple(record.get("grid_fields", ())))
    return plots.final_results(curves)


__all__ = ["Run", "evaluate_policy", "open_run", "resume", "train"]
