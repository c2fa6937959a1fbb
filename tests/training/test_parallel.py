"""Seeds x hyperparameters in one program (and over two devices) equal the single runs.

What "the same" means here: initial states are bitwise equal. After one chunk (250 iterations,
218 gradient updates), integer and boolean leaves (counters, env times, stored flags, PRNG keys)
are bitwise equal and float leaves agree to 1e-5. Not bitwise, because XLA compiles a vmapped
(batched) matmul and its reductions to other kernels than the single-run ones, so sums are
rounded in another order: measured max difference 2.4e-7 after one chunk.

Why one chunk: training amplifies rounding. Adam divides by the gradient's running RMS, so
where a gradient is nearly zero (a flat direction of the loss) a rounding-sized difference
becomes a full-size step. Measured on this probe, seed 2 drifts 5e-5 after two chunks and 1e-3
after three while every integer leaf still agrees; on the Truncation probe (values independent
of the action, so the actor's gradient is pure rounding noise) two chunks already drift 5e-3.
That is the optimisation's sensitivity, not a difference between the programs, so the programs
are compared before it dominates.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import compile_level
import jax
import numpy as np
import pytest
from probe_runs import probe_config, probe_hparams, train

from rl_jax.agents.td3 import td3
from rl_jax.training import device_layout, parallel, params

ENV_ID = "rl_jax/ProbeActionReward-v0"
CHUNKS = 1
GRID = {"actor_lr": [1e-3, 3e-4], "tau": [0.05, 0.005]}


def _numpy(x):
    """A host copy; typed PRNG keys become their raw key data."""
    if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
        x = jax.random.key_data(x)
    return np.array(x)


def _leaves(tree):
    return [_numpy(x) for x in jax.tree.leaves(tree)]


def assert_same(got, expected, atol=1e-5):
    got_leaves, expected_leaves = _leaves(got), _leaves(expected)
    assert len(got_leaves) == len(expected_leaves)
    for a, b in zip(got_leaves, expected_leaves, strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        if np.issubdtype(a.dtype, np.floating):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=atol)
        else:
            np.testing.assert_array_equal(a, b)


def _run_parallel(num_hparams, hparams, seeds, loop_seeds=False):
    config = probe_config(ENV_ID)
    runner = parallel.Program(
        td3, config, num_hparams=num_hparams, num_seeds=len(seeds), loop_seeds=loop_seeds
    )
    keys = parallel.seed_keys(seeds)
    state = runner.init(keys, hparams)
    initial = jax.tree.map(_numpy, state)  # copied now: train_chunk donates the state
    history = []
    for _ in range(CHUNKS):
        state, metrics = runner.train_chunk(state, hparams)
        history.append(metrics)
    return initial, state, history


@pytest.fixture(scope="module")
def grid_run():
    """The 2x2 grid of (actor_lr, tau), one seed, as one program on one device."""
    hparams, combos = params.grid(probe_hparams(), **GRID)
    return combos, _run_parallel(4, hparams, [0])


def test_vmap_over_three_seeds_equals_each_seed_alone(three_seeds_run):
    seeds = [0, 1, 2]
    initial, state, history = three_seeds_run
    config = probe_config(ENV_ID)
    for index, seed in enumerate(seeds):
        alone = td3.init(jax.random.key(seed), config, probe_hparams())
        assert_same(parallel.select(initial, 0, index), alone, atol=0.0)  # bitwise
        single_state, single_history = train(ENV_ID, seed=seed, chunks=CHUNKS)
        assert_same(parallel.select(state, 0, index), single_state)
        for chunk, single in zip(history, single_history, strict=True):
            assert_same(jax.tree.map(lambda x, i=index: x[0, i], chunk), single)
    # The seeds really are different runs.
    assert not np.allclose(
        state.agent.actor["params"]["MLP_0"]["Dense_0"]["kernel"][0, 0],
        state.agent.actor["params"]["MLP_0"]["Dense_0"]["kernel"][0, 1],
    )


def test_two_by_two_hyperparameter_grid_equals_four_single_runs(grid_run):
    combos, (_, state, history) = grid_run
    assert [tuple(c.values()) for c in combos] == [
        (1e-3, 0.05),
        (1e-3, 0.005),
        (3e-4, 0.05),
        (3e-4, 0.005),
    ]
    finals = []
    for index, combo in enumerate(combos):
        overrides = tuple(sorted(combo.items()))
        single_state, single_history = train(ENV_ID, chunks=CHUNKS, hparam_overrides=overrides)
        assert_same(parallel.select(state, index, 0), single_state)
        assert_same(jax.tree.map(lambda x, i=index: x[i, 0], history[-1]), single_history[-1])
        lr = parallel.select(state, index, 0).agent.actor_opt.hyperparams["learning_rate"]
        assert float(lr) == pytest.approx(combo["actor_lr"])
        finals.append(_leaves(single_state.agent.target_critics)[0])
    # Different hyperparameters gave different runs (the comparison is not vacuous).
    assert all(not np.allclose(finals[0], other) for other in finals[1:])


# One child process with two CPU devices for both tests below that need them (each fresh
# interpreter imports JAX and the package again): the sharded grid and padded seeds, unless this
# process computes on another backend and so has no one-device runs to compare them with; then
# the device layouts that ``program_for`` picks for each learner.
TWO_DEVICE_SCRIPT = textwrap.dedent(
    """
    import json, sys
    from pathlib import Path
    from rl_jax.training.jax_setup import configure
    configure(cpu_devices=2)  # before JAX starts
    import jax, numpy as np
    sys.path[:0] = [{tests!r}, {helpers!r}]
    from test_parallel import ENV_ID, GRID, _leaves, _run_parallel
    from probe_runs import probe_config, probe_hparams
    from rl_jax.agents.dqn import dqn
    from rl_jax.agents.td3 import td3
    from rl_jax.run.plan import program_for
    from rl_jax.run.spec import RunSpec
    from rl_jax.training import parallel, params
    assert len(jax.devices()) == 2
    result = {{}}
    if {sharded!r}:
        hparams, _ = params.grid(probe_hparams(), **GRID)
        _, state, history = _run_parallel(4, hparams, [0])
        devices = {{d.id for d in state.agent.critics["params"]["MLP_0"]["Dense_0"]["kernel"]
                   .sharding.device_set}}
        np.savez({out!r}, *_leaves((state, history)))
        # 3 seeds on 2 devices: padded to 2 + 2 (a copy of seed 0 computed and dropped).
        runner = parallel.Program(td3, probe_config(ENV_ID), num_hparams=1, num_seeds=3)
        assert (runner.layout.seed_split, runner.layout.padded_seeds) == (2, 4)
        one = params.stack([probe_hparams()])
        padded = runner.init(parallel.seed_keys([0, 1, 2]), one)
        padded, metrics = runner.train_chunk(padded, one)
        np.savez({padded_out!r}, *_leaves((runner.unpad(padded, one), runner.gather(metrics))))
        result["devices"] = len(devices)

    def layout(algorithm, env_id, seeds):
        config, hparams = algorithm.default_config(env_id), algorithm.default_hyperparams(env_id)
        spec = RunSpec(algorithm, env_id, config, (hparams,), Path("unused"), seeds=seeds)
        program = program_for(spec)
        return [program.layout.devices, program.layout.padded_seeds]

    result["layouts"] = [
        layout(td3, "rl_jax/Pendulum-v1", 5),
        layout(td3, "rl_jax/Pendulum-v1", 1),
        layout(td3, "rl_jax/HalfCheetah-v5", 5),
        layout(dqn, "rl_jax/CartPole-v1", 5),
    ]
    print(json.dumps(result))
    """
)
ON_CPU = jax.default_backend() == "cpu"


@pytest.fixture(scope="module")
def two_device_child(tmp_path_factory):
    """``(the child's JSON result, the sharded run's files)``; the child on the CPU, with this
    process's compile flags only (its own device count)."""
    folder = tmp_path_factory.mktemp("two_devices")
    files = {"out": folder / "sharded.npz", "padded_out": folder / "padded.npz"}
    script = TWO_DEVICE_SCRIPT.format(
        tests=str(Path(__file__).parent),
        helpers=str(Path(__file__).resolve().parents[1]),
        sharded=ON_CPU,
        **{name: str(path) for name, path in files.items()},
    )
    env = {**os.environ, "XLA_FLAGS": compile_level.subprocess_flags(), "JAX_PLATFORMS": "cpu"}
    result = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1]), files


@pytest.fixture(scope="module")
def three_seeds_run():
    """Seeds 0, 1, 2 with the probe hyperparameters, as one program on one device."""
    return _run_parallel(1, params.stack([probe_hparams()]), [0, 1, 2])


def test_seeds_as_a_loop_equal_seeds_vmapped(three_seeds_run):
    """``loop_seeds`` (each seed's ops of their own, for conv nets) computes what the vmap does,
    in the same [H, S] layout, clock shared."""
    looped = _run_parallel(1, params.stack([probe_hparams()]), [0, 1, 2], loop_seeds=True)
    for got, expected in zip(looped, three_seeds_run, strict=True):
        assert_same(got, expected)


def _load(path: Path) -> list[np.ndarray]:
    with np.load(path) as saved:
        return [saved[f"arr_{i}"] for i in range(len(saved.files))]


def _assert_leaves_close(got: list[np.ndarray], expected: list[np.ndarray]) -> None:
    assert len(got) == len(expected)
    for a, b in zip(got, expected, strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        if np.issubdtype(a.dtype, np.floating):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)
        else:
            np.testing.assert_array_equal(a, b)


@pytest.mark.skipif(
    not ON_CPU,
    reason="compares a run on two CPU devices with this process's runs, which are not on the CPU",
)
def test_sharded_over_two_cpu_devices_equals_one_device(
    grid_run, three_seeds_run, two_device_child
):
    result, files = two_device_child
    assert result["devices"] == 2  # both devices held runs
    _, (_, state, history) = grid_run
    _assert_leaves_close(_load(files["out"]), _leaves((state, history)))
    # The padded 3-seed run returns exactly the 3 real seeds, equal to the one-device run.
    _, state, history = three_seeds_run
    _assert_leaves_close(_load(files["padded_out"]), _leaves((state, history[0])))


def test_mesh_splits_runs_evenly_and_select_keeps_the_shared_clock():
    assert device_layout.mesh_shape(2, 3, num_devices=2) == (2, 1)
    assert device_layout.mesh_shape(1, 4, num_devices=2) == (1, 2)
    assert device_layout.mesh_shape(4, 4, num_devices=2) == (1, 2)  # seeds split first
    assert device_layout.mesh_shape(1, 3, num_devices=2) == (1, 1)  # 3 runs cannot split in two
    assert device_layout.mesh_shape(3, 2, num_devices=4) == (3, 1)  # 3 of 4 devices beat 2
    state = td3.init(jax.random.key(0), probe_config(ENV_ID), probe_hparams())
    stacked = jax.tree.map(lambda x: x[None, None], state).replace(clock=state.clock)
    assert parallel.state_axes(state).clock is None
    one = parallel.select(stacked, 0, 0)
    assert_same(one, state, atol=0.0)


def test_layout_pads_uneven_runs_to_use_every_device():
    five = device_layout.plan_layout(1, 5, num_devices=2)
    assert (five.seed_split, five.padded_seeds, five.runs_per_device, five.padding) == (2, 6, 3, 1)
    assert device_layout.plan_layout(1, 1, num_devices=2).devices == 1  # one run stays whole
    assert device_layout.plan_layout(1, 4, num_devices=2).padding == 0
    grid = device_layout.plan_layout(3, 1, num_devices=2)  # 3 configs x 1 seed: split configs
    assert (grid.hparam_split, grid.padded_hparams, grid.runs_per_device) == (2, 4, 2)
    # 3 configs x 2 seeds: the 2 seeds stay together (no block holds a lone seed), so the
    # configs split, padded to 2 + 2
    six = device_layout.plan_layout(3, 2, num_devices=2)
    assert (six.hparam_split, six.seed_split, six.padding, six.runs_per_device) == (2, 1, 2, 4)
    unpadded = device_layout.plan_layout(1, 5, num_devices=2, pad=False)
    assert (unpadded.devices, unpadded.padding) == (1, 0)
    edge = parallel._pad_edge(np.arange(6).reshape(2, 3), (3, 4))
    np.testing.assert_array_equal(edge, [[0, 1, 2, 0], [3, 4, 5, 3], [0, 1, 2, 0]])


def test_every_learner_spreads_uneven_runs_over_both_devices(two_device_child):
    """``program_for``: 5 seeds pad to 3 + 3 whatever the learner and network width (one
    compiled program, the copy dropped); one seed stays whole. (The CPU's layout, on a GPU
    too.)"""
    assert two_device_child[0]["layouts"] == [[2, 6], [1, 1], [2, 6], [2, 6]]
