"""The command line: flags from dataclasses, --help, and every bad input ending in one line on
stderr with a non-zero status, no traceback, and existing runs untouched (real subprocesses)."""

import dataclasses
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import fake_algorithm as fake
import pytest
from child_env import python_path
from run_helpers import leaves_bytes, snapshot

from rl_jax import errors
from rl_jax.run import cli, command, field_docs, flags, learners, recipe_choice
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.plan import make_plan
from rl_jax.run.run_dir import CHECKPOINT_DIR, identity_hash
from rl_jax.run.script import Script
from rl_jax.run.spec import RunSpec
from rl_jax.run.start import fresh_start
from rl_jax.training import params

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "tests" / "fake_experiment.py"
# A user's shell: without the TF_CPP_MIN_LOG_LEVEL=1 that importing jax (conftest) put into this
# process's environment, which would let XLA log a warning line on every compilation-cache hit.
ENV = {
    **{key: value for key, value in os.environ.items() if key != "TF_CPP_MIN_LOG_LEVEL"},
    "PYTHONPATH": python_path(ROOT),
}


def start(args: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(SCRIPT), *args],
        cwd=cwd,
        env=ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


# ---- in-process: flags and help -------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Base:
    alpha: float = 0.5
    """Docstring style."""


@dataclasses.dataclass(frozen=True)
class Documented(Base):
    beta: int = 3  # trailing comment style
    # comment above,
    # over two lines
    gamma: tuple[int, ...] = (1, 2)
    delta: bool = False


def test_field_docs_reads_docstrings_comments_and_bases():
    docs = field_docs.field_docs(Documented)
    assert docs == {
        "alpha": "Docstring style.",
        "beta": "trailing comment style",
        "gamma": "comment above, over two lines",
    }
    assert field_docs.undocumented_fields(Documented()) == ["delta"]
    assert field_docs.undocumented_fields(fake.default_config()) == []
    assert field_docs.undocumented_fields(fake.default_hyperparams()) == []


def test_help_documents_every_flag(capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.run_experiment(fake, fake.ENV_ID, "Fake experiment.", ["--help"])
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for flag in ("--seeds", "--total-steps", "--out", "--resume", "--gif", "--grid"):
        assert flag in text
    assert "--buffer-size INT Replay buffer capacity in transitions. (default: 64)" in text
    assert "--batch-size INT transitions per gradient update (default: 8)" in text
    assert "--learning-rate FLOAT Adam learning rate. (default: 0.01)" in text
    assert "--hidden-sizes INT,... Widths of the policy's hidden layers. (default: 8)" in text
    assert "--deterministic-init, --no-deterministic-init" in text
    choice = command.choose(command.read([]), fake, fake.ENV_ID)
    parser, _, _ = command.help_parser(choice, "", cli.Defaults())
    for action in parser._actions:
        assert action.help and action.help.strip(), action.option_strings


def test_generic_help_without_an_algorithm(capsys):
    assert cli.run_experiment(None, None, "Sweep.", ["--help"]) == 0
    text = capsys.readouterr().out
    assert "--algo" in text and "--env" in text and "--seeds" in text


def test_value_parsers():
    assert errors.parse_int("1e6") == 1_000_000 and errors.parse_int("1_000") == 1000
    assert flags.parse_bool("yes") is True and flags.parse_bool("0") is False
    for parse, text in (
        (errors.parse_int, "2.5"),
        (errors.parse_float, "nan"),
        (errors.parse_float, "x"),
    ):
        with pytest.raises(Exception, match="invalid"):
            parse(text)


def test_grid_parsing_checks_names_and_types():
    hparams, config = fake.default_hyperparams(), fake.default_config()
    grid = flags.parse_grid(["learning-rate=1e-3,3e-3", "updates_per_step=1,2"], hparams, config)
    assert grid == {"learning_rate": [1e-3, 3e-3], "updates_per_step": [1, 2]}
    expanded = params.expand(hparams, grid)
    assert [(h.learning_rate, h.updates_per_step) for h in expanded] == [
        (1e-3, 1),
        (1e-3, 2),
        (3e-3, 1),
        (3e-3, 2),
    ]
    bad = {
        "updates_per_step=1,2.5": "takes int values",
        "learning_rate=0.1,fast": "takes float values",
        "num_envs=2,4": "static config field",
        "nonsense=1": "unknown hyperparameter",
        "learning_rate": "expected NAME=V1,V2",
    }
    for spec, message in bad.items():
        with pytest.raises(errors.UsageError, match=message):
            flags.parse_grid([spec], hparams, config)


def test_default_run_dir_names_env_algorithm_and_time(tmp_path, monkeypatch):
    monkeypatch.setattr(command, "RUNS_ROOT", tmp_path)
    first = command.default_run_dir("rl_jax/HalfCheetah-v5", "td3")
    assert first.parent == tmp_path and first.name.startswith("HalfCheetah-v5__td3__")
    first.mkdir()
    assert command.default_run_dir("rl_jax/HalfCheetah-v5", "td3") != first


# ---- subprocesses: a real run, then every bad input ----------------------------------------


def overwrite_with_garbage(step_dir: Path) -> None:
    for path in step_dir.rglob("*"):
        if path.is_file():
            path.write_bytes(b"\x93garbage\xff" * 3)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A finished run made by the script, and damaged or foreign copies of it."""
    root = tmp_path_factory.mktemp("cli")
    process = start(["--out", "existing", "--log-interval", "0", "--gif"], root)
    out, err = process.communicate(timeout=600)
    assert process.returncode == 0, err
    existing = root / "existing"
    copies = {}
    for name, change in {
        "foreign_env": lambda r: r["identity"].update(env_id="rl_jax/Pendulum-v1"),
        "foreign_algorithm": lambda r: r["identity"].update(algorithm="td3"),
        "edited": lambda r: r["identity"].update(seeds=3),
    }.items():
        shutil.copytree(existing, root / name)
        record = json.loads((root / name / "config.json").read_text())
        change(record)
        if name != "edited":  # another run, recorded as such (hash and config's env id agree)
            record["identity"]["config"]["env_id"] = record["identity"]["env_id"]
            record["identity_hash"] = identity_hash(record["identity"])
        (root / name / "config.json").write_text(json.dumps(record))
        copies[name] = root / name
    shutil.copytree(existing, root / "corrupt")
    # A run shorter than the checkpoint interval has its final checkpoint only: nothing older to
    # fall back on once it is damaged.
    [only] = list((root / "corrupt" / CHECKPOINT_DIR).iterdir())
    overwrite_with_garbage(only)
    return {
        "root": root,
        "stdout": out,
        "existing": existing,
        **copies,
        "corrupt": root / "corrupt",
    }


def test_a_cli_run_prints_plan_progress_and_results(workspace):
    out, existing = workspace["stdout"], workspace["existing"]
    assert "plan: fake on rl_jax/FakePoint-v0, 2 seeds" in out
    assert "compiled in" in out and "env steps/s" in out and "ETA" in out
    assert "final eval return at step 100 (2 seeds)" in out
    assert f"run directory: {Path('existing')}" in out
    for name in ("config.json", "metrics.jsonl", "curves.png", "results.txt", "policy.gif"):
        assert (existing / name).is_file()
    assert "rendered seed" in out
    record = json.loads((existing / "config.json").read_text())
    assert "fake_experiment.py --out existing --log-interval 0 --gif" in record["command"]


BAD_INPUTS = {
    "unknown env": (
        ["--generic", "--algo", "fake", "--env", "Nope-v0"],
        "unknown environment 'Nope-v0'; known environments: ",
    ),
    "unknown algorithm": (
        ["--generic", "--algo", "nope", "--env", fake.ENV_ID],
        "unknown algorithm 'nope'; known algorithms: ",
    ),
    "zero seeds": (["--seeds", "0"], "argument --seeds: must be >= 1, got 0"),
    "negative seeds": (["--seeds", "-3"], "argument --seeds: must be >= 1, got -3"),
    "zero steps": (["--total-steps", "0"], "argument --total-steps: must be >= 1"),
    "negative count": (["--num-envs", "-1"], "--num-envs must be >= 0, got -1"),
    "non-numeric value": (
        ["--learning-rate", "abc"],
        "argument --learning-rate: invalid numeric value: 'abc'",
    ),
    "non-integer value": (["--batch-size", "8.5"], "argument --batch-size: invalid integer"),
    "grid value of the wrong type": (
        ["--grid", "updates_per_step=1,2.5"],
        "--grid updates_per_step takes int values",
    ),
    "grid value not a number": (["--grid", "learning_rate=0.1,fast"], "takes float values"),
    "grid over a static field": (["--grid", "num_envs=2,4"], "is a static config field"),
    "resume of a missing dir": (["--resume", "{root}/missing"], "no run directory at"),
    "resume of another env": (
        ["--resume", "{foreign_env}"],
        "it is a fake run on rl_jax/Pendulum-v1, this is fake on rl_jax/FakePoint-v0",
    ),
    "resume of another algorithm": (["--resume", "{foreign_algorithm}"], "it is a td3 run"),
    "resume of an edited record": (
        ["--resume", "{edited}"],
        "is refused: its identity was edited after the run wrote it",
    ),
    "resume with another config": (
        ["--resume", "{existing}", "--learning-rate", "0.5"],
        "it is a different run (learning_rate 0.01 vs 0.5)",
    ),
    "resume of a corrupt checkpoint": (
        ["--resume", "{corrupt}"],
        "; there is no older checkpoint to resume from",
    ),
    "out dir with a different run": (
        ["--out", "{existing}", "--noise", "0.1"],
        "already holds a different run (noise 0.3 vs 0.1)",
    ),
    "out dir with the same run": (["--out", "{existing}"], "continue it with --resume"),
    "replay buffer smaller than a batch": (
        ["--buffer-size", "4"],  # the fake's batch is 8
        "--buffer-size must be >= 8 (--batch-size: every update draws a batch from it), got 4",
    ),
    "replay buffer too big": (
        ["--buffer-size", "2000000000", "--seeds", "40"],
        "the train state needs 1.75 TB (buffer 1.75 TB",
    ),
}


def recipe_of(argv, algorithm, env_id):
    """The recipe that a script of ``algorithm`` on ``env_id`` runs for ``argv``."""
    return command.choose(command.read(argv), algorithm, env_id).recipe


def test_a_recipe_is_whole_and_an_unknown_one_is_one_error():
    from rl_jax.agents.td3 import td3

    cheetah = "rl_jax/HalfCheetah-v5"
    recipe = recipe_of(["--recipe", "gpu", "--seeds", "2"], td3, cheetah)
    assert (recipe.name, recipe.total_steps) == ("gpu", 250_000)
    default = recipe_of(["--seeds", "2"], td3, cheetah)
    assert default.name == "default" and default.throughput == (280.0, 5)
    assert recipe_of(["--recipe=default"], td3, cheetah) is default
    with pytest.raises(cli.UsageError, match="--recipe short: td3 has no such recipe for rl_jax/"):
        recipe_of(["--recipe", "short"], td3, cheetah)
    # a learner without recipes has only its defaults
    assert recipe_of([], fake, fake.ENV_ID).name == "default"
    with pytest.raises(cli.UsageError, match="known: default$"):
        recipe_of(["--recipe", "paper"], fake, fake.ENV_ID)


def test_algo_picks_the_learner_and_recipe_one_of_its_recipes():
    """--recipe never switches the learner by splitting its name: a script of a fixed learner
    takes the explicit aliases that recorded commands use, and every other spelling of another
    learner's recipe is one line saying what to type instead."""
    from rl_jax.agents.td3 import td3

    cheetah = "rl_jax/HalfCheetah-v5"
    for spelling, (learner, recipe) in recipe_choice.RECIPE_ALIASES.items():
        chosen, name = recipe_choice.script_recipe(td3, spelling)
        assert (chosen.name, name) == (learner, recipe)
        assert recipe_choice.recipe_named(chosen, cheetah, name).name == recipe
        with pytest.raises(cli.UsageError, match=f"is {learner}'s: --algo {learner} --recipe"):
            recipe_choice.recipe_named(td3, cheetah, spelling)  # --algo td3 --recipe td7-cpu
    assert recipe_choice.script_recipe(td3, "paper") == (td3, "paper")
    with pytest.raises(cli.UsageError, match=r"\(ppo-cleanrl is ppo's: --algo ppo --recipe clean"):
        recipe_choice.recipe_named(td3, cheetah, "ppo-cleanrl")
    assert recipe_choice.resumed_learner(td3, "td7").name == "td7"
    assert recipe_choice.resumed_learner(td3, "dqn") is td3


def test_a_recipe_is_recorded_in_the_runs_command(monkeypatch, tmp_path):
    """The command a run records reruns it: --recipe (which is taken out of the flags before
    parsing) is part of it, as typed."""
    from rl_jax.agents.td3 import td3
    from rl_jax.run import runner

    class Stop(Exception):
        pass

    specs = []

    def capture(spec):
        specs.append(spec)
        raise Stop

    monkeypatch.setattr(runner, "run", capture)
    script = Script(td3, "rl_jax/Pendulum-v1", total_steps=100)
    out = str(tmp_path / "run")
    with pytest.raises(Stop):
        script.main("", ["--recipe", "paper", "--seeds", "2", "--out", out])
    assert specs[0].config.batch_size == 256 and specs[0].throughput is None
    assert specs[0].command.endswith(f"--recipe paper --seeds 2 --out {out}")
    with pytest.raises(Stop):
        script.main("", ["--seeds", "2", "--out", out])
    assert specs[1].config.actor_hidden == (64, 64) and specs[1].throughput == (830.0, 5)
    assert (
        specs[1].command.endswith(f"--seeds 2 --out {out}") and "--recipe" not in specs[1].command
    )


# Run as real processes: one line and no traceback from a fresh interpreter, including the
# checkpoint read that fails inside orbax (its late callbacks must not print at exit). The other
# cases call the same entry point in this process, which is much faster.
SUBPROCESS_CASES = ("unknown env", "resume of a corrupt checkpoint")


def run_in_process(argv: list[str]) -> tuple[str, str, int]:
    """``fake_experiment.py argv`` without a new interpreter: (stdout, stderr, status)."""
    import contextlib
    import io

    generic = "--generic" in argv
    argv = [arg for arg in argv if arg != "--generic"]
    defaults = cli.Defaults(seeds=2, total_steps=100)
    algorithm, env_id = (None, None) if generic else (fake, fake.ENV_ID)
    out, err = io.StringIO(), io.StringIO()
    xla_flags = os.environ.get("XLA_FLAGS")
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = errors.guard(lambda: cli.run_experiment(algorithm, env_id, "", argv, defaults))
        except SystemExit as exit_info:  # argparse errors exit from inside the parser
            status = exit_info.code
    if xla_flags is None:  # run_experiment sets the device count for a process not started yet
        os.environ.pop("XLA_FLAGS", None)
    else:
        os.environ["XLA_FLAGS"] = xla_flags
    return out.getvalue(), err.getvalue(), status


@pytest.fixture(scope="module")
def bad_input_results(workspace):
    """Every bad input; the runs' files before and after."""
    learners.register_algorithm("fake", "fake_algorithm")
    names = ("existing", "foreign_env", "foreign_algorithm", "edited", "corrupt")
    before = {name: snapshot(workspace[name]) for name in names}
    formatted = {
        case: [arg.format(**{k: str(v) for k, v in workspace.items()}) for arg in args]
        for case, (args, _) in BAD_INPUTS.items()
    }
    cwd = os.getcwd()
    os.chdir(workspace["root"])  # relative paths resolve as for the script
    try:
        results = {
            case: run_in_process(argv)
            for case, argv in formatted.items()
            if case not in SUBPROCESS_CASES
        }
    finally:
        os.chdir(cwd)
    processes = {case: start(formatted[case], workspace["root"]) for case in SUBPROCESS_CASES}
    for case, process in processes.items():
        results[case] = (*process.communicate(timeout=600), process.returncode)
    after = {name: snapshot(workspace[name]) for name in names}
    return results, before, after


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_is_one_line_on_stderr(bad_input_results, case):
    results, _, _ = bad_input_results
    stdout, stderr, code = results[case]
    assert code != 0
    assert "Traceback" not in stderr + stdout, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("error: ")
    assert BAD_INPUTS[case][1] in lines[0]


def test_bad_inputs_leave_existing_runs_untouched(bad_input_results, workspace):
    _, before, after = bad_input_results
    assert after == before
    created = {p.name for p in workspace["root"].iterdir()}
    assert created == {"existing", "foreign_env", "foreign_algorithm", "edited", "corrupt"}
    assert not (workspace["root"] / "runs").exists()


def test_sigterm_checkpoints_exits_zero_and_resume_is_bit_identical(workspace):
    root = workspace["root"]
    args = [
        "--out",
        "stopped",
        "--total-steps",
        "2000",
        "--log-interval",
        "0",
        "--checkpoint-interval",
        "1e9",
    ]
    # The reference: the same run never stopped, made by the same script (so on the same device
    # layout: a batch split differently over devices may round differently), started beside it.
    unstopped = [*args, "--out", "unstopped"]
    unstopped.remove("stopped")
    unstopped.remove("--out")
    reference = start(unstopped, root)
    process = start(args, root)
    for line in process.stdout:
        if line.startswith("step "):  # training has started
            process.send_signal(signal.SIGTERM)
            break
    out, err = process.communicate(timeout=600)
    assert process.returncode == 0, err
    assert "Traceback" not in err
    assert "SIGTERM: stopping after this chunk" in out
    resume_line = next(line for line in out.splitlines() if line.startswith("resume with: "))
    command = shlex.split(resume_line.removeprefix("resume with: "))
    assert command[1:] == [str(SCRIPT), "--resume", "stopped"]
    with Checkpointer(root / "stopped" / CHECKPOINT_DIR, read_only=True) as checkpointer:
        stopped_at = checkpointer.latest_step()
    assert stopped_at < 2000 and f"stopped at step {stopped_at:,} of 2,000" in out
    resumed = subprocess.run(
        [sys.executable, *command[1:]],
        cwd=root,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"resuming from the checkpoint at step {stopped_at:,}" in resumed.stdout
    _, err = reference.communicate(timeout=600)
    assert reference.returncode == 0, err
    config = dataclasses.replace(fake.default_config(), iterations_per_chunk=5)
    spec = RunSpec(fake, fake.ENV_ID, config, (fake.default_hyperparams(),), root, seeds=2)
    plan = make_plan(spec)
    final = {}
    for name in ("stopped", "unstopped"):
        with Checkpointer(root / name / CHECKPOINT_DIR, read_only=True) as checkpointer:
            assert checkpointer.latest_step() == 2000
            final[name] = checkpointer.restore(plan.template)[0]
    assert leaves_bytes(final["stopped"]) == leaves_bytes(final["unstopped"])
    # Training happened between the stop and the end (the comparison is not of two copies).
    fresh = fresh_start(spec, plan).state
    fresh = plan.program.unpad(fresh, params.stack([fake.default_hyperparams()]))
    assert leaves_bytes(fresh) != leaves_bytes(final["stopped"])


def test_a_resume_past_a_damaged_latest_checkpoint_says_one_line_and_keeps_it(tmp_path):
    """From a fresh interpreter, as a user runs it: the one warning line is all of stderr (no
    traceback, none of orbax's log lines about the damaged files), and the run carries on."""
    args = ["--total-steps", "40", "--checkpoint-interval", "0", "--log-interval", "0"]
    # The run to damage is made in this process; its resume is the fresh interpreter.
    _, err, status = run_in_process(["--out", str(tmp_path / "run"), *args])
    assert status == 0, err
    overwrite_with_garbage(tmp_path / "run" / CHECKPOINT_DIR / "40")
    resumed = start(["--resume", "run"], tmp_path)
    out, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("warning: checkpoint step 40 is unreadable (")
    assert "resuming from the checkpoint at step 20 (chunk 1)" in out
    kept = [p.name for p in (tmp_path / "run" / CHECKPOINT_DIR).iterdir()]
    assert sorted(name[:11] for name in kept) == ["20", "40", "damaged-40-"]


def test_a_named_recipe_reaches_the_run_with_its_overrides_for_the_chosen_env(monkeypatch):
    """train.py's whole path, flags to the run's spec: --recipe paper-2018 on Ant starts learning
    after 10,000 random steps as the paper's Ant runs did, not the recipe's 1,000."""
    from rl_jax.run import runner

    specs = []

    class Stop(Exception):
        pass

    def capture(spec):
        specs.append(spec)
        raise Stop

    monkeypatch.setattr(runner, "run", capture)
    for env_id, starts in (("rl_jax/Ant-v5", 10_000), ("rl_jax/Hopper-v5", 1_000)):
        argv = ["--algo", "td3", "--env", env_id, "--recipe", "paper-2018", "--seeds", "2"]
        with pytest.raises(Stop):
            cli.run_experiment(argv=argv)
        config = specs[-1].config
        assert (config.learning_starts, config.batch_size) == (starts, 100), env_id
        assert config.actor_hidden == (400, 300)


def test_train_py_offers_the_learners_recipes_as_whole_recipes():
    from rl_jax.agents.td3 import ddpg, td3

    hopper, cheetah = "rl_jax/Hopper-v5", "rl_jax/HalfCheetah-v5"
    chosen = recipe_of(["--recipe", "paper", "--seeds", "2"], td3, hopper)
    assert chosen.name == "paper" and chosen.throughput is None
    config, hparams = recipe_choice.recipe_settings(td3, hopper, chosen)
    rates = hparams.to_dict()
    # the TD3 paper's loop, networks and rates, where Hopper's own recipe is the CPU one
    loop = (config.num_envs, config.updates_per_iteration, config.batch_size)
    assert loop == (1, 1, 256) and config.learning_starts == 25_000
    assert (config.actor_hidden, config.critic_hidden) == ((256, 256), (256, 256))
    assert [rates["actor_lr"], rates["critic_lr"]] == pytest.approx([3e-4, 3e-4])
    own = td3.default_config(hopper)
    assert (own.num_envs, own.actor_hidden) == (4, (128, 128))
    # the paper's own 2018 runs: 400 x 300 at 1e-3, batch 100, and 1,000 random steps on Hopper
    # but 10,000 on Ant and half cheetah (their own recipe of that name)
    for env_id, starts in ((hopper, 1_000), ("rl_jax/Ant-v5", 10_000), (cheetah, 10_000)):
        config = td3.default_config(env_id, "paper-2018")
        rates = td3.default_hyperparams(env_id, "paper-2018").to_dict()
        loop = (config.num_envs, config.updates_per_iteration, config.batch_size)
        assert loop == (1, 1, 100) and config.learning_starts == starts, env_id
        assert (config.actor_hidden, config.critic_hidden) == ((400, 300), (400, 300))
        assert [rates["actor_lr"], rates["critic_lr"]] == pytest.approx([1e-3, 1e-3])
    # DDPG stays DDPG under the paper's loop
    ddpg_config = ddpg.default_config(hopper, "paper")
    assert (ddpg_config.num_critics, ddpg_config.policy_delay, ddpg_config.num_envs) == (1, 1, 1)
    assert float(ddpg.default_hyperparams(hopper, "paper").target_noise) == 0.0
    with pytest.raises(cli.UsageError, match="starts a new run"):
        recipe_choice.recipe_named(td3, hopper, "paper", resuming=True)
    # --help lists them with their summaries
    choice = command.choose(command.read(["--algo", "td3", "--env", hopper]), None, None)
    parser, _, _ = command.help_parser(choice, "", cli.Defaults())
    text = " ".join(parser.format_help().split())
    assert "paper: the TD3 repository's recipe since 2019" in text
    assert "paper-2018: the settings of the TD3 paper's own runs" in text
