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
or jax without a record the test skips and prints the values to add.

The record is of XLA's default compile flags, which the rest of the suite does not use
(``compile_level.py``). With the suite's flags the programs of 0e5ccfd and of today differ in the
last bits (XLA's older emitters fuse the two differently); at LLVM -O0 alone they are equal, as at
the default flags. So the runs are made in a subprocess: inside the suite at -O0 alone, against
``RECORDED_O0``; with ``TEST_XLA_OPT=default`` at the default flags, against ``RECORDED``
(``python tests/agents/test_td3_reference.py td3 ddpg_3_step`` prints them).
"""

import json
import subprocess
import sys

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
# (cpu tag, jax version) -> run name -> (eval returns [chunk][seed], {group: [sums per seed]})
RECORDED = {
    # AMD EPYC (its flags include AVX-512), jax 0.9.2 (the pin), recorded at 0e5ccfd.
    ("f5c94f1c7303", "0.9.2"): {
        "td3": (
            [[-1553.412109375, -1470.27783203125], [-1474.2796630859375, -1596.7691650390625]],
            {
                "actor": [-4.640931472182274, 11.054214596748352],
                "critics": [49.83023130893707, 35.87864822149277],
                "target_actor": [-4.712959110736847, 5.541360467672348],
                "target_critics": [27.1879942715168, 19.322303231805563],
            },
        ),
        "ddpg_3_step": (
            [[-1595.5263671875, -1507.7882080078125], [-1546.3040771484375, -1476.16259765625]],
            {
                "actor": [-5.155573718249798, 19.147892877459526],
                "critics": [45.851603511720896, 14.97144003212452],
                "target_actor": [-5.517106413841248, 11.38016191124916],
                "target_critics": [30.79944349080324, 9.53616900742054],
            },
        ),
    },
}
# The same runs compiled at LLVM -O0 alone (``compile_level.FLAG``, XLA's newer emitters kept),
# the flags the test's subprocess uses inside the suite: recorded at 0e5ccfd on 2026-11-28, and
# today's code gave the same bits.
RECORDED_O0 = {
    ("f5c94f1c7303", "0.9.2"): {
        "td3": (
            [[-1553.4119873046875, -1470.27783203125], [-1474.2830810546875, -1596.7691650390625]],
            {
                "actor": [-4.640874423086643, 11.054214358329773],
                "critics": [49.82920065522194, 35.87864534556866],
                "target_actor": [-4.712945722043514, 5.541362717747688],
                "target_critics": [27.187927186489105, 19.32230557873845],
            },
        ),
        "ddpg_3_step": (
            [[-1595.527099609375, -1507.7880859375], [-1545.9373779296875, -1476.1627197265625]],
            {
                "actor": [-5.108353182673454, 19.147894844412804],
                "critics": [45.850541457533836, 14.971440568566322],
                "target_actor": [-5.509666532278061, 11.38016563653946],
                "target_critics": [30.798675037920475, 9.536173366010189],
            },
        ),
    },
}
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


@pytest.fixture(scope="module")
def fingerprints():
    """``(fingerprint of every run of RUNS, the record for those flags)``, the runs made in one
    subprocess at XLA's default flags, or at -O0 alone inside the suite (half the compile time;
    XLA's older emitters of the suite's own flags are left out, see above)."""
    import compile_level

    env = compile_level.default_level_env()
    records = RECORDED
    if compile_level.active():
        env["XLA_FLAGS"] = f"{env['XLA_FLAGS']} {compile_level.FLAG}".strip()
        records = RECORDED_O0
    result = subprocess.run(
        [sys.executable, __file__, *RUNS], env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1]), records


@pytest.mark.parametrize("name", list(RUNS))
def test_options_off_is_bit_identical_to_plain_td3(name, fingerprints):
    got, records = fingerprints[0][name], fingerprints[1]
    where = (jax_setup.cpu_tag(), jax.__version__)
    recorded = records.get(where, {}).get(name)
    if recorded is None:
        pytest.skip(f"no reference for (CPU, jax) {where}; this one gives {got!r}")
    assert got[0] == recorded[0]
    assert got[1] == recorded[1]


if __name__ == "__main__":  # the named runs' fingerprints as JSON, at this process's XLA flags
    from rl_jax.training.jax_setup import configure

    configure()
    names = sys.argv[1:]
    print(json.dumps({name: fingerprint(RUNS[name][0], **RUNS[name][1]) for name in names}))
