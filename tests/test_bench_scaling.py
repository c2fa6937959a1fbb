"""The scaling tables of ``bench.scaling``: byte counts by hand, and the tables' shapes."""

import jax
import jax.numpy as jnp

from bench import scaling


def test_tree_bytes_counts_by_hand():
    tree = {
        "weights": jax.ShapeDtypeStruct((3, 4), jnp.float32),  # 48
        "count": jax.ShapeDtypeStruct((), jnp.int32),  # 4
        "flags": jax.ShapeDtypeStruct((5,), jnp.bool_),  # 5
        "key": jax.eval_shape(lambda: jax.random.key(0)),  # threefry: 2 x uint32 = 8
    }
    assert scaling.tree_bytes(tree) == 48 + 4 + 5 + 8
    assert scaling.tree_bytes(None) == 0


def test_run_bytes_of_a_small_run():
    run = scaling.run_bytes("td3 pendulum", "td3", "rl_jax/Pendulum-v1")
    assert 0 < run.buffer < run.state
    assert 0 < run.policy < run.state
    assert run.metrics > 0


def test_tables_shape():
    run = scaling.RunBytes("tiny", state=1000, buffer=900, policy=50, metrics=8)
    rows = scaling.growth_rows(run)
    assert len(rows) == len(scaling.HOSTS)
    assert all(len(row) == 9 for row in rows)
    last = rows[-1]
    assert last[2] == str(scaling.HOSTS[-1] * scaling.SEEDS_PER_HOST)
    assert last[3] == scaling.format_bytes(scaling.HOSTS[-1] * scaling.SEEDS_PER_HOST * 8)
    growth = scaling.growth_table([run, run]).splitlines()
    assert len(growth) == 2 + 2 * len(scaling.HOSTS)
    assert all(line.count("|") == 10 for line in growth)
    sweep = scaling.sweep_table([run]).splitlines()
    assert len(sweep) == 3 and all(line.count("|") == 7 for line in sweep)
    assert scaling.format_bytes(scaling.SWEEP_RUNS * 1000) in sweep[-1]
