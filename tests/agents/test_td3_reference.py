"""Plain TD3 and DDPG stay bit for bit what they were before the TD7/CrossQ/SimBa options existed.

Every option of ``rl_jax.agents.td3`` is off by default, and with all of them off a short run must
end with exactly the parameters and evaluation returns recorded at commit 0e5ccfd (before the
options were added): 2 seeds vmapped in one program on ``rl_jax/Pendulum-v1``, 2 chunks of 200
env steps each (100 random warm-up steps, then one update per env step).

The fingerprint of a run is, per seed, the sum over a network's parameter leaves of each leaf's
float32 sum, and the evaluation return after each chunk. XLA compiles for the CPU it runs on and
the same program can round differently on another CPU model (DESIGN.md, "The machines vary"),
so the values are kept per ``jax_setup.cpu_tag()`` and jax version (another XLA fuses and rounds
the same program differently too: jax 0.12 moved the last bit of some of these sums); on a CPU
or jax without a record the test skips, before running anything, and names the command that prints
the values to add to ``tests/data/td3_fingerprints.json``.

The first record was made at XLA's default compile flags, which the rest of the suite does not use
(``compile_level.py``). With the suite's flags the programs of 0e5ccfd and of today differ in the
last bits (XLA's older emitters fuse the two differently); at LLVM -O0 alone they are equal, as at
the default flags. So the runs are made in a subprocess: inside the suite at -O0 alone, against
the "-O0" record; with ``TEST_XLA_OPT=default`` at the default flags, against the "default" one
(``python tests/agents/test_td3_reference.py td3 ddpg_3_step`` prints them).
"""

import json
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from rl_jax.agents.td3 import ddpg, td3
from rl_jax.training import jax_setup, parallel, params

GROUPS = ("actor", "critics", "target_actor", "target_critics")
TINY = {
    "num_envs": 2,
    "learning_starts": 100,
    "iterations_per_chunk": 100,
    "batch_size": 32,
    "buffer_size": 1000,
    "actor_hidden": (16, 16),
    "critic_hidden": (16, 16),
}
# The records: tests/data/td3_fingerprints.json, one per (CPU tag, jax version, flags), each with
# run name -> [eval returns [chunk][seed], {group: [sums per seed]}]; flags "default" are XLA's,
# "-O0" LLVM -O0 alone (``compile_level.FLAG``).
RECORDS = Path(__file__).resolve().parents[1] / "data" / "td3_fingerprints.json"


def recorded(cpu_tag: str, jax_version: str, flags: str) -> dict:
    """The record's runs for this CPU, jax and flags, or {} where there is none."""
    for record in json.loads(RECORDS.read_text()):
        if (record["cpu_tag"], record["jax"], record["flags"]) == (cpu_tag, jax_version, flags):
            return record["runs"]
    return {}


RUNS = {"td3": (td3, {}), "ddpg_3_step": (ddpg, {"n_step": 3})}


def fingerprint(algorithm, **config_overrides):
    """``(eval returns [chunk][seed], {group: [per-seed sums]})`` of the tiny 2-seed run."""
    config = algorithm.default_config("rl_jax/Pendulum-v1", **{**TINY, **config_overrides})
    hparams = params.stack([algorithm.default_hyperparams("rl_jax/Pendulum-v1")])
    program = parallel.Program(algorithm, config, 1, 2, devices=jax.devices()[:1])
    state = program.init(parallel.seed_keys([0, 1]), hparams)
    returns = []
    for _ in range(2):
        state, metrics = program.train_chunk(state, hparams)
        returns.append(np.asarray(program.gather(metrics).eval_return)[0].tolist())
    agent = program.unpad(state, hparams).agent
    sums = {
        group: [
            sum(float(np.sum(np.asarray(leaf)[0, seed])) for leaf in jax.tree.leaves(part))
            for seed in range(2)
        ]
        for group, part in ((group, getattr(agent, group)) for group in GROUPS)
    }
    return returns, sums


def _run_env() -> tuple[dict[str, str], str]:
    """The environment of the runs' subprocess and the flags of their record: XLA's default
    flags, or -O0 alone inside the suite (half the compile time; XLA's older emitters of the
    suite's own flags are left out, see above)."""
    import compile_level

    env = compile_level.default_level_env()
    if not compile_level.active():
        return env, "default"
    env["XLA_FLAGS"] = f"{env['XLA_FLAGS']} {compile_level.FLAG}".strip()
    return env, "-O0"


@pytest.fixture(scope="module")
def fingerprints() -> dict:
    """The fingerprint of every run of RUNS, made in one subprocess (``_run_env``)."""
    result = subprocess.run(
        [sys.executable, __file__, *RUNS],
        env=_run_env()[0],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("name", list(RUNS))
def test_options_off_is_bit_identical_to_plain_td3(name, request):
    env, flags = _run_env()
    where = (jax_setup.cpu_tag(), jax.__version__, flags)
    record = recorded(*where).get(name)
    if record is None:  # nothing to compare with: the runs are not made
        command = f"XLA_FLAGS='{env['XLA_FLAGS']}' python tests/agents/{Path(__file__).name} {name}"
        pytest.skip(f"no record for (CPU, jax, flags) {where}; `{command}` prints this host's")
    got = request.getfixturevalue("fingerprints")[name]
    assert got[0] == record[0]
    assert got[1] == record[1]


if __name__ == "__main__":  # the named runs' fingerprints as JSON, at this process's XLA flags
    from rl_jax.training.jax_setup import configure

    configure()
    names = sys.argv[1:]
    print(json.dumps({name: fingerprint(RUNS[name][0], **RUNS[name][1]) for name in names}))
