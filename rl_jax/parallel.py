"""Seeds x hyperparameter sets as one compiled program, split over the local devices.

``jit(vmap(vmap(train_chunk)))``: the outer vmap runs over a stack of ``H`` hyperparameter
pytrees, the inner over ``S`` seed keys, so every leaf of the train state gains ``[H, S]`` leading
axes. Seed ``s`` uses the same key under every hyperparameter set (common random numbers: a sweep
compares configurations on identical initialisations and noise).

The ``[H, S]`` grid is split over a device mesh with axes ``("hparams", "seeds")`` through
``shard_map``: each device runs the same vmapped program on its block of runs with no
communication. On a CPU-only machine, ``rl_jax.jax_setup.configure(cpu_devices=2)`` (before JAX
starts) exposes both cores as devices.

The train state's ``clock`` (counters that depend only on the static config) is *not* stacked:
it is identical across runs, stays unbatched under vmap (so the learner's branches on it stay real
branches) and is replicated over devices. ``select`` extracts one run's state.

Usage::

    runner = parallel.Runner(td3, config, num_hparams=2, num_seeds=3)
    state = runner.init(parallel.seed_keys([0, 1, 2]), parallel.stack([hp_a, hp_b]))
    state, metrics = runner.train_chunk(state, hparams)   # metrics leaves [H, S]
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from rl_jax.algorithm import Algorithm

AXES = ("hparams", "seeds")
SHARED_FIELD = "clock"  # the train-state field kept unbatched and replicated


def stack(trees: Sequence[Any]) -> Any:
    """Stack pytrees of the same structure along a new leading axis."""
    return jax.tree.map(lambda *leaves: jnp.stack([jnp.asarray(x) for x in leaves]), *trees)


def grid(base: Any, **values: Sequence[float]) -> tuple[Any, list[dict[str, float]]]:
    """Every combination of the given field values on top of ``base`` (a struct dataclass):
    ``(stacked pytree [H], [{field: value}, ...])``, first field varying slowest."""
    names = list(values)
    combos = [
        dict(zip(names, combo, strict=True))
        for combo in itertools.product(*(values[n] for n in names))
    ]
    trees = [base.replace(**{k: jnp.asarray(v, jnp.float32) for k, v in c.items()}) for c in combos]
    return stack(trees), combos


def seed_keys(seeds: Sequence[int]) -> jax.Array:
    """``[S]`` typed PRNG keys; seed ``s`` gets ``jax.random.key(s)`` as a single run would."""
    return jnp.stack([jax.random.key(int(s)) for s in seeds])


def state_axes(state: Any) -> Any:
    """vmap axes for a train state: 0 everywhere, ``None`` for the shared ``clock``."""
    axes = jax.tree.map(lambda _: 0, state)
    if hasattr(axes, SHARED_FIELD):
        axes = axes.replace(**{SHARED_FIELD: None})
    return axes


def select(state: Any, hparam_index: int, seed_index: int) -> Any:
    """One run's state out of a stacked ``[H, S]`` state."""
    axes = state_axes(state)
    return jax.tree.map(
        lambda axis, leaf: leaf if axis is None else leaf[hparam_index, seed_index],
        axes,
        state,
        is_leaf=lambda x: x is None,
    )


def mesh_shape(num_hparams: int, num_seeds: int, num_devices: int) -> tuple[int, int]:
    """``(hparam_split, seed_split)``: the most devices that split the ``[H, S]`` runs evenly,
    splitting seeds first. (3 seeds x 1 set on 2 devices can only use 1 device.)"""
    for used in range(num_devices, 0, -1):
        for seed_split in range(used, 0, -1):
            hparam_split = used // seed_split
            if (
                seed_split * hparam_split == used
                and num_seeds % seed_split == 0
                and num_hparams % hparam_split == 0
            ):
                return hparam_split, seed_split
    raise AssertionError("unreachable: one device always splits the runs")


def make_mesh(num_hparams: int, num_seeds: int, devices: Sequence[Any] | None = None) -> Mesh:
    """A ``("hparams", "seeds")`` device mesh shaped by ``mesh_shape``."""
    devices = list(jax.devices() if devices is None else devices)
    hparam_split, seed_split = mesh_shape(num_hparams, num_seeds, len(devices))
    used = np.array(devices[: hparam_split * seed_split]).reshape(hparam_split, seed_split)
    return Mesh(used, AXES)


def _specs(axes: Any) -> Any:
    runs = PartitionSpec(*AXES)
    return jax.tree.map(
        lambda axis: PartitionSpec() if axis is None else runs, axes, is_leaf=lambda x: x is None
    )


class Runner:
    """Compiled init and chunk for ``[H, S]`` runs of one algorithm and one static config."""

    def __init__(
        self,
        algorithm: Algorithm,
        config: Any,
        num_hparams: int,
        num_seeds: int,
        devices: Sequence[Any] | None = None,
    ):
        self.algorithm, self.config = algorithm, config
        self.num_hparams, self.num_seeds = num_hparams, num_seeds
        self.mesh = make_mesh(num_hparams, num_seeds, devices)
        self._init = None
        self._chunk = None

    def _axes_and_specs(self, hparams: Any) -> tuple[Any, Any]:
        one = jax.tree.map(lambda x: x[0], hparams)
        abstract = jax.eval_shape(
            lambda key: self.algorithm.init(key, self.config, one), jax.random.key(0)
        )
        axes = state_axes(abstract)
        return axes, _specs(axes)

    def _build(self, hparams: Any) -> None:
        algorithm, config = self.algorithm, self.config
        axes, state_specs = self._axes_and_specs(hparams)
        runs, by_seed, by_hparam = (
            PartitionSpec(*AXES),
            PartitionSpec(AXES[1]),
            PartitionSpec(AXES[0]),
        )

        def init_one(key, hp):
            return algorithm.init(key, config, hp)

        init = jax.vmap(init_one, in_axes=(0, None), out_axes=axes)
        init = jax.vmap(init, in_axes=(None, 0), out_axes=axes)
        # check_vma=False: each device's block is an independent program; the replication check
        # would demand casts inside every learner's branches for no benefit.
        init = jax.shard_map(
            init,
            mesh=self.mesh,
            in_specs=(by_seed, by_hparam),
            out_specs=state_specs,
            check_vma=False,
        )
        self._init = jax.jit(init)

        def chunk_one(state, hp):
            return algorithm.train_chunk(state, config, hp)

        chunk = jax.vmap(chunk_one, in_axes=(axes, None), out_axes=(axes, 0))
        chunk = jax.vmap(chunk, in_axes=(axes, 0), out_axes=(axes, 0))
        chunk = jax.shard_map(
            chunk,
            mesh=self.mesh,
            in_specs=(state_specs, by_hparam),
            out_specs=(state_specs, runs),
            check_vma=False,
        )
        # The old state is dead after a chunk: donating it lets XLA update the replay buffer
        # in place instead of holding two copies.
        self._chunk = jax.jit(chunk, donate_argnums=0)

    def init(self, keys: jax.Array, hparams: Any) -> Any:
        """Fresh ``[H, S]`` state from ``[S]`` keys and ``[H]``-stacked hyperparameters."""
        self._check(keys.shape[0], hparams)
        if self._init is None:
            self._build(hparams)
        return self._init(keys, hparams)

    def train_chunk(self, state: Any, hparams: Any) -> tuple[Any, Any]:
        """One chunk for every run. ``state`` is donated: use the returned one."""
        if self._chunk is None:
            self._build(hparams)
        return self._chunk(state, hparams)

    def sharding(self, spec: PartitionSpec | None = None) -> NamedSharding:
        return NamedSharding(self.mesh, PartitionSpec(*AXES) if spec is None else spec)

    def _check(self, num_keys: int, hparams: Any) -> None:
        sizes = {leaf.shape[0] for leaf in jax.tree.leaves(hparams)}
        if num_keys != self.num_seeds or sizes != {self.num_hparams}:
            raise ValueError(
                f"expected {self.num_seeds} keys and hyperparameters stacked to "
                f"{self.num_hparams}, got {num_keys} keys and leading sizes {sorted(sizes)}"
            )
