"""Real TD3 through the command line: a stopped and resumed run ends bit-identical to one that
never stopped, and the bad inputs only a real learner can show (a resume of another algorithm's
or env's run, a replay buffer too big for memory) end in one line with the estimate."""

import dataclasses
from pathlib import Path

import pytest
from run_helpers import leaves_bytes, snapshot

from rl_jax import cli
from rl_jax.checkpoint import Checkpointer
from rl_jax.runner import CHECKPOINT_DIR, make_plan
from rl_jax.td3 import ddpg, td3

ENV_ID = "rl_jax/Pendulum-v1"
# Tiny and fast: 2 envs x 50 iterations = 100 env steps per chunk; updates from step 100.
FLAGS = [
    "--num-envs", "2", "--updates-per-iteration", "2", "--iterations-per-chunk", "50",
    "--learning-starts", "100", "--batch-size", "32", "--buffer-size", "1000",
    "--num-eval-envs", "2", "--actor-hidden", "16,16", "--critic-hidden", "16,16",
    "--seeds", "2", "--log-interval", "0", "--checkpoint-interval", "0",
]  # fmt: skip
CHUNK = 100


def run_cli(algorithm, env_id, argv) -> int:
    return cli.guard(lambda: cli.run_experiment(algorithm, env_id, "", argv))


def final_state(run_dir: Path, algorithm=td3, env_id=ENV_ID):
    """The latest checkpoint of a run directory, and its step."""
    args, names = _parsed(algorithm, env_id)
    spec = cli.build_spec(args, algorithm, env_id, cli.Defaults(), names, [])
    plan = make_plan(dataclasses.replace(spec, out=run_dir))
    with Checkpointer(run_dir / CHECKPOINT_DIR, read_only=True) as checkpointer:
        state, meta = checkpointer.restore(plan.template)
    return state, meta["step"]


def _parsed(algorithm, env_id):
    parser, config_names, hparam_names = cli.build_parser(
        algorithm, env_id, "", cli.Defaults(), choose=False
    )
    return parser.parse_args(FLAGS), (config_names, hparam_names)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """4 chunks in one go; and 2 chunks, stopped, then resumed to 4."""
    root = tmp_path_factory.mktemp("td3")
    assert (
        run_cli(
            td3, ENV_ID, [*FLAGS, "--total-steps", str(4 * CHUNK), "--out", str(root / "whole")]
        )
        == 0
    )
    assert (
        run_cli(
            td3, ENV_ID, [*FLAGS, "--total-steps", str(2 * CHUNK), "--out", str(root / "split")]
        )
        == 0
    )
    stopped = final_state(root / "split")
    assert (
        run_cli(td3, ENV_ID, ["--resume", str(root / "split"), "--total-steps", str(4 * CHUNK)])
        == 0
    )
    return root, stopped


def test_resumed_td3_run_is_bit_identical_to_an_unstopped_one(runs, capsys):
    root, (stopped_state, stopped_step) = runs
    whole, whole_step = final_state(root / "whole")
    resumed, resumed_step = final_state(root / "split")
    assert stopped_step == 2 * CHUNK and whole_step == resumed_step == 4 * CHUNK
    assert leaves_bytes(resumed) == leaves_bytes(whole)
    # Updates happened after the resume point: the comparison is of trained parameters.
    assert int(resumed.clock.updates) > int(stopped_state.clock.updates) > 0
    assert leaves_bytes(resumed.agent.actor) != leaves_bytes(stopped_state.agent.actor)


def _one_line_error(capsys, status: int, expected: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert "Traceback" not in captured.err + captured.out
    assert expected in lines[0], lines[0]
    return lines[0]


def test_resume_of_another_algorithm_or_env_is_refused(runs, capsys):
    root, _ = runs
    before = snapshot(root / "whole")
    status = run_cli(ddpg, ENV_ID, ["--resume", str(root / "whole")])
    _one_line_error(capsys, status, "it is a td3 run on rl_jax/Pendulum-v1, this is ddpg on")
    status = run_cli(td3, "rl_jax/Rocket-v0", ["--resume", str(root / "whole")])
    _one_line_error(capsys, status, "this is td3 on rl_jax/Rocket-v0")
    assert snapshot(root / "whole") == before


def test_replay_buffer_too_big_is_refused_before_allocating(tmp_path, capsys):
    out = tmp_path / "big"
    argv = ["--buffer-size", "4e9", "--seeds", "5", "--out", str(out)]
    line = _one_line_error(capsys, run_cli(td3, ENV_ID, argv), "the train state needs ")
    # 5 seeds x 4e9 transitions x (obs 3 + action 1 + reward + next obs 3 + 2 flags) x 4 bytes.
    assert "buffer " in line and "TB" in line and "of memory is available" in line
    assert not out.exists()
