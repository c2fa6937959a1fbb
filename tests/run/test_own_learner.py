"""A learner of the user's own (``examples/expected_sarsa.py``) through the command line, as
docs/own_learner.md uses it: trained by file and by module name, resumed bit for bit, swept,
evaluated, rendered and loaded; every way of naming it wrongly is one line; and opening a run
never imports a learner the run's record names (a learner file that leaves a marker when it is
imported is recorded, and the marker never appears)."""

import contextlib
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from child_env import python_path

import rl_jax
from rl_jax.errors import RunError, UsageError, guard
from rl_jax.run import cli, evaluate, learners, render, sweep

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "expected_sarsa.py"
BY_FILE = "examples/expected_sarsa.py:learner"  # relative to the repository root, the cwd
BY_MODULE = "examples.expected_sarsa:learner"
# A user's shell (see test_cli.py): without the TF_CPP_MIN_LOG_LEVEL that importing jax set here.
ENV = {
    **{key: value for key, value in os.environ.items() if key != "TF_CPP_MIN_LOG_LEVEL"},
    "PYTHONPATH": python_path(ROOT),
}
# Tiny: 4 envs x 25 iterations = 100 env steps per seed and chunk, a checkpoint after each.
FLAGS = [
    "--env", "rl_jax/CartPole-v1", "--hidden", "8", "--num-envs", "4",
    "--iterations-per-chunk", "25", "--num-eval-envs", "2", "--log-interval", "0",
    "--checkpoint-interval", "0",
]  # fmt: skip


def start(script: str, args: list[str]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(ROOT / "experiments" / script), *args],
        cwd=ROOT,
        env=ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(process: subprocess.Popen) -> tuple[str, str, int]:
    out, err = process.communicate(timeout=600)
    return out, err, process.returncode


def ok(process: subprocess.Popen) -> str:
    out, err, code = finish(process)
    assert code == 0 and "Traceback" not in err, err
    return out


def one_line(err: str, code: int, expected: str) -> None:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err and expected in lines[0], lines[0]


def rows(run_dir: Path) -> list[dict]:
    lines = (run_dir / "metrics.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(line).items() if k != "wall_time"} for line in lines]


def in_process(argv: list[str]) -> tuple[str, str, int]:
    """``experiments/train.py argv`` in this process, faster than a new one: (stdout, stderr,
    status), relative paths from the repository root as for the scripts."""
    out, err = io.StringIO(), io.StringIO()
    xla_flags, cwd = os.environ.get("XLA_FLAGS"), os.getcwd()
    os.chdir(ROOT)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = guard(lambda: cli.run_experiment(None, None, "", argv))
    finally:
        os.chdir(cwd)
        if xla_flags is None:  # run_experiment sets the device count for a fresh process
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = xla_flags
    return out.getvalue(), err.getvalue(), status


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A sweep of 2 learning rates through the script, by file; beside it, in this process
    through train.py's code: 4 chunks in one go (with a GIF, rendered by a child process), by
    file; and 2 chunks by module name, then resumed to 4 (first naming another learner)."""
    root = tmp_path_factory.mktemp("own_learner")
    grid = ["--grid", "learning_rate=1e-3,3e-4", "--seeds", "1", "--total-steps", "200"]
    sweeping = start("sweep.py", ["--algo", BY_FILE, *FLAGS, *grid, "--out", str(root / "sweep")])
    two = [*FLAGS, "--seeds", "2"]
    whole = ["--algo", BY_FILE, *two, "--total-steps", "400", "--out", str(root / "whole")]
    split = ["--algo", BY_MODULE, *two, "--total-steps", "200", "--out", str(root / "split")]
    resume = ["--resume", str(root / "split"), "--total-steps", "400"]
    printed = {
        "whole": in_process([*whole, "--gif"]),
        "split": in_process(split),
        "another": in_process([*resume, "--algo", "td3"]),
        "resumed": in_process([*resume, "--algo", BY_FILE]),  # trained by module name
        "sweep": finish(sweeping),
    }
    for name in ("whole", "split", "resumed", "sweep"):
        assert printed[name][2] == 0 and "Traceback" not in printed[name][1], printed[name][1]
    return root, printed


def test_a_run_records_where_its_learner_came_from(runs):
    root, printed = runs
    record = json.loads((root / "whole" / "config.json").read_text())
    assert record["identity"]["algorithm"] == "expected_sarsa"
    assert record["learner"] == f"file:{EXAMPLE}:learner"
    split = json.loads((root / "split" / "config.json").read_text())
    assert split["learner"] == "module:examples.expected_sarsa:learner"
    assert "plan: expected_sarsa on rl_jax/CartPole-v1, 2 seeds" in printed["whole"][0]
    assert (root / "whole" / "policy.gif").stat().st_size > 100  # its child was given --algo
    assert "rendered seed" in printed["whole"][0]


def test_a_resume_names_the_learner_again_and_equals_never_stopping(runs):
    """Trained by module name, resumed by file: one learner, however it is named."""
    root, printed = runs
    one_line(
        *printed["another"][1:],
        f"cannot resume {root / 'split'}: it is a expected_sarsa run on rl_jax/CartPole-v1, this "
        "is td3",
    )
    assert "resuming from the checkpoint at step 200" in printed["resumed"][0]
    whole, resumed = rows(root / "whole"), rows(root / "split")
    assert len(whole) == 8 and resumed == whole  # every metric of every chunk, bit for bit
    assert whole[-1]["updates"] == 100 and whole[-1]["loss"] != whole[0]["loss"]


def test_a_sweep_of_two_learning_rates(runs):
    root, _ = runs
    saved = json.loads((root / "sweep" / "sweep.json").read_text())
    assert saved["learner"] == f"file:{EXAMPLE}:learner"
    assert saved["algo"] == f"{EXAMPLE}:learner"  # absolute: a resume from anywhere names it
    table = (root / "sweep" / "results.txt").read_text()
    assert "learning_rate=0.001" in table and "learning_rate=0.0003" in table
    run_rows = rows(root / "sweep" / "base")
    assert {row["config"] for row in run_rows} == {0, 1} and run_rows[-1]["step"] == 200


def test_its_policy_loads_and_evaluates_with_the_learner_named(runs, capsys):
    root, _ = runs  # (and renders: the GIF of the run above)
    policy = rl_jax.load_policy(root / "whole", algorithm=f"{EXAMPLE}:learner")
    assert policy(np.zeros(4, np.float32)) in (0, 1)
    assert policy(np.zeros((3, 4), np.float32)).shape == (3,)
    argv = [str(root / "whole"), "--episodes", "2", "--algo", f"{EXAMPLE}:learner"]
    assert evaluate.main(argv) == 0
    assert "each policy on 2 fresh episodes" in capsys.readouterr().out


# ---- naming a learner wrongly: one line each -------------------------------------------------

INCOMPLETE = """
class Incomplete:
    name = "incomplete"

    def default_config(self, env_id): ...

    def default_hyperparams(self, env_id=None): ...

    def init(self, key, config, hparams): ...

    def policy(self, state, config): ...


learner = Incomplete()
"""


def test_every_wrong_name_is_one_line(tmp_path):
    (tmp_path / "incomplete.py").write_text(INCOMPLETE)
    cases = {
        # the known names (built-in, and those registered in this process) are listed between
        "nope": "unknown algorithm 'nope'; known algorithms: ",
        "no_such_package.learners:learner": "cannot import module 'no_such_package.learners' "
        "for the learner no_such_package.learners:learner (No module named 'no_such_package')",
        "examples/missing.py:learner": "no learner file examples/missing.py",
        "examples/expected_sarsa.py:lerner": "examples/expected_sarsa.py has no attribute "
        "'lerner' (learners in it: learner)",
        "examples.expected_sarsa:lerner": "examples.expected_sarsa has no attribute 'lerner'",
        f"{tmp_path}/incomplete.py:learner": f"{tmp_path}/incomplete.py:learner has no "
        "train_chunk(state, config, hparams)",
        "examples.expected_sarsa:Config": "examples.expected_sarsa:Config has no name",
        "examples/expected_sarsa.py": "examples/expected_sarsa.py has no name (a string: the "
        "learner's name in run directories); the learners in it: "
        "examples/expected_sarsa.py:learner",
    }
    out = str(tmp_path / "out")
    for name, expected in cases.items():
        one_line(*in_process(["--algo", name, *FLAGS, "--out", out])[1:], expected)
    pendulum = ["--algo", BY_FILE, *FLAGS, "--env", "rl_jax/Pendulum-v1", "--out", out]
    one_line(*in_process(pendulum)[1:], "expected SARSA needs discrete actions, not Box(")
    assert not Path(out).exists()
    with pytest.raises(UsageError, match="has no name"):
        rl_jax.train(object(), "rl_jax/CartPole-v1")


def test_register_algorithm_names_a_learner_of_ones_own(runs):
    root, _ = runs
    record = json.loads((root / "whole" / "config.json").read_text())
    learners.register_algorithm("sarsa", f"{EXAMPLE}:learner")
    try:
        learner = learners.resolve("sarsa")
        assert learner.name == "expected_sarsa"
        assert learners.resolve(learner) is learner  # the object itself, from Python
        # Registered in this process, so named: the run opens without algorithm=.
        assert learners.for_run(record, root / "whole") is learner
    finally:
        del learners.ALGORITHMS["sarsa"]


# ---- opening a run never imports its recorded learner --------------------------------------

MARKER_LEARNER = """
from pathlib import Path

Path(__file__).with_name("imported").write_text("this file was imported")
"""


def _plant(root: Path, tmp_path: Path) -> tuple[Path, Path, Path]:
    """Copies of a run and a sweep whose records name ``planted.py`` as their learner."""
    planted = tmp_path / "planted.py"
    planted.write_text(MARKER_LEARNER)
    run_dir, sweep_dir = tmp_path / "run", tmp_path / "sweep"
    shutil.copytree(root / "whole", run_dir)
    shutil.copytree(root / "sweep", sweep_dir)
    for path in (run_dir / "config.json", sweep_dir / "base" / "config.json"):
        record = json.loads(path.read_text())
        record["learner"] = record["algorithm_module"] = f"file:{planted}:learner"
        record["learner_source"] = "sha256:" + hashlib.sha256(planted.read_bytes()).hexdigest()
        path.write_text(json.dumps(record))
    saved = json.loads((sweep_dir / "sweep.json").read_text())
    saved.update(learner=f"file:{planted}:learner", algo=f"{planted}:learner")
    (sweep_dir / "sweep.json").write_text(json.dumps(saved))
    return planted, run_dir, sweep_dir


def test_opening_a_run_never_imports_the_learner_its_record_names(runs, tmp_path, capsys):
    planted, run_dir, sweep_dir = _plant(runs[0], tmp_path)
    named = f"name it again: --algo {planted}:learner"
    # A fresh process: the script's resume.
    _, err, code = finish(start("train.py", ["--resume", str(run_dir)]))
    one_line(err, code, named)
    # Every other way in, in this process.
    for main in (evaluate.main, render.main):
        status = main([str(run_dir)])
        one_line(capsys.readouterr().err, status, named)
    status = guard(lambda: sweep.run_sweep(["--resume", str(sweep_dir)]))
    one_line(capsys.readouterr().err, status, named)
    in_python = f"name it again: algorithm='{planted}:learner'"
    for open_it in (
        lambda: rl_jax.load_policy(run_dir),
        lambda: rl_jax.resume(run_dir, quiet=True),
        lambda: rl_jax.open_run(run_dir).evaluate(1),
        lambda: rl_jax.open_run(run_dir).save_gif(tmp_path / "p.gif"),
    ):
        with pytest.raises(RunError, match=in_python):
            open_it()
    # A learner of the run's name named from another file opens it, with one warning line for
    # its other source, having imported only the one named.
    rl_jax.load_policy(run_dir, algorithm=f"{EXAMPLE}:learner")
    assert "source differs" in capsys.readouterr().err
    assert not (tmp_path / "imported").exists()
    assert not any("planted" in name for name in sys.modules)


def test_a_run_travels_with_its_learner(runs, tmp_path, capsys):
    """A run moved to another folder opens with the learner's file wherever it now lies: a copy
    of the file, or the module by name, is the same learner; an edited copy opens with one
    warning line; a learner of another name is refused."""
    moved = tmp_path / "elsewhere" / "run"
    shutil.copytree(runs[0] / "whole", moved)
    copy = tmp_path / "project" / "sarsa_copy.py"
    copy.parent.mkdir()
    shutil.copy(EXAMPLE, copy)
    record = json.loads((moved / "config.json").read_text())
    assert record["learner_source"].startswith("sha256:")
    for named in (f"{copy}:learner", BY_MODULE):
        policy = rl_jax.load_policy(moved, seed=0, algorithm=named)
        assert np.asarray(policy(np.zeros(4, np.float32))).shape == ()
        assert capsys.readouterr().err == ""
    edited = tmp_path / "project" / "sarsa_edited.py"
    edited.write_text(EXAMPLE.read_text() + "\n# an edit after the run\n")
    rl_jax.load_policy(moved, seed=0, algorithm=f"{edited}:learner")
    rl_jax.load_policy(moved, seed=1, algorithm=f"{edited}:learner")
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: ") and "source differs" in lines[0]
    renamed = tmp_path / "project" / "sarsa_renamed.py"
    renamed.write_text(EXAMPLE.read_text().replace('name = "expected_sarsa"', 'name = "other"'))
    with pytest.raises(RunError, match="is a expected_sarsa run, not a other run"):
        rl_jax.load_policy(moved, algorithm=f"{renamed}:learner")


RAISING_LEARNER = """
raise RuntimeError("the learner's module fails while it runs")
"""


def test_a_learner_module_that_raises_or_a_class_is_one_line(tmp_path):
    raising = tmp_path / "raising_learner.py"
    raising.write_text(RAISING_LEARNER)
    with pytest.raises(UsageError) as failed:
        learners.resolve(f"{raising}:learner")
    message = str(failed.value)
    assert "\n" not in message and "RuntimeError: the learner's module fails" in message
    with pytest.raises(UsageError, match="is the class ExpectedSarsa, not a learner: name an"):
        learners.resolve(f"{EXAMPLE}:ExpectedSarsa")
    # and through the script: one line, no traceback
    _, err, code = in_process(["--algo", f"{raising}:learner", *FLAGS])
    one_line(err, code, "RuntimeError: the learner's module fails")
