"""Seeds x hyperparameter sets as one compiled program, split over the local devices.

``jit(vmap(vmap(train_chunk)))``: the outer vmap runs over a stack of ``H`` hyperparameter
pytrees, the inner over ``S`` seed keys, so every leaf of the train state gains ``[H, S]`` leading
axes. Seed ``s`` uses the same key under every hyperparameter set (common random numbers: a sweep
compares configurations on identical initialisations and noise).

The ``[H, S]`` grid is split over a device mesh with axes ``("hparams", "seeds")`` through
``shard_map``: each device runs the same vmapped program on its block of runs with no
communication. Runs that do not split evenly are padded with copies of the first seed (or
hyperparameter set) that are computed and dropped: 5 seeds on 2 devices run as 3 + 3
(``plan_layout``). The mesh may span several processes started with ``jax.distributed``. On a
CPU-only machine, ``rl_jax.training.jax_setup.configure(cpu_devices=2)`` (before JAX starts)
exposes both cores as devices.

The train state's ``clock`` (counters that depend only on the static config) is *not* stacked:
it is identical across runs, stays unbatched under vmap (so the learner's branches on it stay real
branches) and is replicated over devices. ``select`` extracts one run's state.

Usage::

    program = parallel.Program(td3, config, num_hparams=2, num_seeds=3)
    state = program.init(parallel.seed_keys([0, 1, 2]), params.stack([hp_a, hp_b]))
    state, metrics = program.train_chunk(state, hparams)   # metrics leaves [H, S]
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from typing import Any, TypeAlias, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from rl_jax.training.algorithm import (
    Algorithm,
    ChunkMetrics,
    Config,
    Hyperparams,
    SharesClock,
    TrainState,
)
from rl_jax.training.device_layout import AXES, plan_layout

_PROGRAMS: dict[tuple, tuple[jax.stages.Wrapped, jax.stages.Wrapped]] = {}  # see Program._build
_COMPILED: dict[tuple, jax.stages.Compiled] = {}  # the chunk compiled ahead of time, per program
SHARED_FIELD = "clock"  # the train-state field kept unbatched and replicated

#: vmap axes of a train state: the state's own dataclass with 0 at every leaf, ``None`` at the
#: shared clock
Axes: TypeAlias = TrainState
#: a pytree mapped leaf by leaf into one of the same structure
Tree = TypeVar("Tree")
#: ``(state, hparams) -> (state, metrics)`` of one run, or of a stack of them
Chunk = Callable[[TrainState, Hyperparams], tuple[TrainState, ChunkMetrics]]


def seed_keys(seeds: Sequence[int]) -> jax.Array:
    """``[S]`` typed PRNG keys; seed ``s`` gets ``jax.random.key(s)`` as a single run would."""
    return jnp.stack([jax.random.key(int(s)) for s in seeds])


_ONE_RUN_SHAPES: dict[tuple, TrainState] = {}
_ONE_RUN_SHAPES_KEPT = 32


def one_run_shapes(algorithm: Algorithm, config: Config, hparams: Hyperparams) -> TrainState:
    """``jax.ShapeDtypeStruct`` tree of one run's state (``init`` at the first of the stacked
    ``hparams``), nothing allocated. Planning a run, placing it and writing its checkpoint
    template each need it; tracing ``init`` once per learner, config and hyperparameters (kept
    for the last few) spares the others their own trace. A learner or config that cannot be
    hashed (a user's mutable dataclass) is traced every time."""
    one = jax.tree.map(lambda x: np.asarray(x[0]), hparams)
    leaves, structure = jax.tree.flatten(one)
    key: tuple | None = (
        algorithm,
        config,
        structure,
        tuple((x.dtype.str, x.tobytes()) for x in leaves),
    )
    try:
        hash(key)
    except TypeError:
        key = None
    if key is None or key not in _ONE_RUN_SHAPES:
        values = jax.tree.map(jnp.asarray, one)
        shapes = jax.eval_shape(lambda rng: algorithm.init(rng, config, values), jax.random.key(0))
        if key is None:
            return shapes
        _ONE_RUN_SHAPES[key] = shapes
        while len(_ONE_RUN_SHAPES) > _ONE_RUN_SHAPES_KEPT:
            del _ONE_RUN_SHAPES[next(iter(_ONE_RUN_SHAPES))]
    return _ONE_RUN_SHAPES[key]


def state_axes(state: TrainState) -> Axes:
    """vmap axes for a train state: 0 everywhere, ``None`` for the shared ``clock``."""
    axes = jax.tree.map(lambda _: 0, state)
    if isinstance(state, SharesClock):
        axes = dataclasses.replace(axes, **{SHARED_FIELD: None})
    return axes


def select(state: TrainState, hparam_index: int, seed_index: int) -> TrainState:
    """One run's state out of a stacked ``[H, S]`` state."""
    axes = state_axes(state)
    return jax.tree.map(
        lambda axis, leaf: leaf if axis is None else leaf[hparam_index, seed_index],
        axes,
        state,
        is_leaf=lambda x: x is None,
    )


def _specs(axes: Axes) -> TrainState:
    runs = PartitionSpec(*AXES)
    return jax.tree.map(
        lambda axis: PartitionSpec() if axis is None else runs, axes, is_leaf=lambda x: x is None
    )


def map_axes(function: Callable[[int | None, Any], Any], axes: Axes, tree: Tree) -> Tree:
    """``function(axis, leaf)`` on every leaf of ``tree``; a ``None`` axis (the shared clock)
    covers a whole subtree, so it is handed to each leaf under it."""
    return jax.tree.map(
        lambda axis, subtree: jax.tree.map(lambda leaf: function(axis, leaf), subtree),
        axes,
        tree,
        is_leaf=lambda x: x is None,
    )


def is_key(leaf: object) -> bool:
    """Whether ``leaf`` is an array of typed PRNG keys."""
    return hasattr(leaf, "dtype") and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key)


def _pad_edge(array: np.ndarray, sizes: tuple[int, ...]) -> np.ndarray:
    """``array`` grown along its leading axes to ``sizes`` by repeating index 0 of each."""
    for axis, size in enumerate(sizes):
        missing = size - array.shape[axis]
        if missing > 0:
            first = np.take(array, [0] * missing, axis=axis)
            array = np.concatenate([array, first], axis=axis)
    return array


def _host(leaf: jax.Array | np.ndarray) -> np.ndarray:
    """A host copy of a (fully addressable) array; typed keys as their key data."""
    if is_key(leaf):
        leaf = jax.random.key_data(leaf)
    return np.asarray(leaf)


def seed_loop(chunk_one: Chunk, axes: Axes, num_seeds: int) -> Chunk:
    """``chunk_one(state, hp)`` over the ``num_seeds`` seeds of an ``[S]`` state as an unrolled
    loop in one program: what ``vmap(chunk_one, in_axes=(axes, None), out_axes=(axes, 0))``
    computes, but each seed keeps its own ops instead of one batched op for all. Vmapped, a conv
    with per-seed weights becomes one grouped conv (slow on XLA's CPU backend) and the conv
    torso's matmuls become batched matmuls; ``python -m bench pixel_dqn`` compares the two.
    Compile time grows with the number of seeds."""

    def looped(state: TrainState, hp: Hyperparams) -> tuple[TrainState, ChunkMetrics]:
        outputs = [
            chunk_one(map_axes(functools.partial(_take, index=i), axes, state), hp)
            for i in range(num_seeds)
        ]
        states = [output[0] for output in outputs]
        stacked = jax.tree.map(
            lambda axis, *runs: runs[0] if axis is None else jax.tree.map(_stack, *runs),
            axes,
            *states,
            is_leaf=lambda x: x is None,
        )
        return stacked, jax.tree.map(_stack, *[output[1] for output in outputs])

    return looped


def _take(axis: int | None, leaf: jax.Array, index: int) -> jax.Array:
    return leaf if axis is None else leaf[index]


def _stack(*leaves: jax.Array) -> jax.Array:
    return jnp.stack(leaves)


class Program:
    """Compiled init and chunk for ``[H, S]`` runs of one algorithm and one static config.

    The state lives on the devices padded to ``layout.padded_hparams x layout.padded_seeds``
    runs; ``unpad``/``gather`` give the ``[H, S]`` runs back on the host and ``place`` puts an
    ``[H, S]`` state (a restored checkpoint) on the devices. The mesh may span the devices of
    several processes (``jax.distributed``): every process then runs the same calls.
    """

    def __init__(
        self,
        algorithm: Algorithm,
        config: Config,
        num_hparams: int,
        num_seeds: int,
        devices: Sequence[jax.Device] | None = None,
        pad: bool = True,
        loop_seeds: bool = False,
    ):
        self.algorithm, self.config = algorithm, config
        self.loop_seeds = loop_seeds
        self.num_hparams, self.num_seeds = num_hparams, num_seeds
        devices = list(jax.devices() if devices is None else devices)
        self.multiprocess = any(d.process_index != jax.process_index() for d in devices)
        whole = len(devices) if self.multiprocess else 1  # every process holds a block
        self.layout = plan_layout(num_hparams, num_seeds, len(devices), pad, min_devices=whole)
        used = np.array(devices[: self.layout.devices])
        self.mesh = Mesh(used.reshape(self.layout.hparam_split, self.layout.seed_split), AXES)
        self.multiprocess = any(d.process_index != jax.process_index() for d in used)
        self._init: jax.stages.Wrapped | None = None
        self._chunk: jax.stages.Wrapped | None = None
        self._axes: Axes | None = None
        self._key_impl: str | None = None
        self._placed_hparams: tuple[Hyperparams, Hyperparams] | None = None
        self._program_key: tuple | None = None

    # ---- shapes and placement -------------------------------------------------------------

    @property
    def padded(self) -> tuple[int, int]:
        """``(hyperparameter sets, seeds)`` as computed, padding included."""
        return self.layout.padded_hparams, self.layout.padded_seeds

    @property
    def devices(self) -> list[jax.Device]:
        """The devices the runs are computed on."""
        return list(self.mesh.devices.flat)

    def gather_each(self, function: Callable[[TrainState], Tree], state: TrainState) -> Tree:
        """``gather(function(state))``: ``function`` of the device state (``[H_padded,
        S_padded]``-leading outputs) as host ``[H, S]`` copies (a ``split_program.SplitProgram``
        calls it once per block of runs)."""
        return self.gather(function(state))

    def sharding(self, spec: PartitionSpec | None = None) -> NamedSharding:
        """The sharding of ``spec`` on the program's mesh (default: runs split over both mesh
        axes).
        """
        return NamedSharding(self.mesh, PartitionSpec(*AXES) if spec is None else spec)

    def axes(self, hparams: Hyperparams) -> Axes:
        """vmap axes of the state (0, or ``None`` for the shared clock)."""
        if self._axes is None:
            self._axes = state_axes(one_run_shapes(self.algorithm, self.config, hparams))
        return self._axes

    def _put(self, array: np.ndarray, sharding: NamedSharding) -> jax.Array:
        if self.multiprocess:
            return jax.make_array_from_callback(array.shape, sharding, lambda index: array[index])
        return jax.device_put(array, sharding)

    def _place_leaf(self, axis: int | None, leaf: jax.Array | np.ndarray) -> jax.Array:
        key_impl = jax.random.key_impl(leaf) if is_key(leaf) else None
        array = _host(leaf)
        if axis is None:
            placed = self._put(array, self.sharding(PartitionSpec()))
        else:
            placed = self._put(_pad_edge(array, self.padded), self.sharding())
        return placed if key_impl is None else jax.random.wrap_key_data(placed, impl=key_impl)

    def place(self, state: TrainState, hparams: Hyperparams) -> TrainState:
        """An ``[H, S]`` state (host or device arrays) padded and put on the mesh."""
        axes = self.axes(hparams)
        return map_axes(self._place_leaf, axes, state)

    def unpad(self, state: TrainState, hparams: Hyperparams) -> TrainState:
        """The ``[H, S]`` runs of a device state, as host arrays (typed keys stay keys)."""
        axes = self.axes(hparams)
        real = (slice(0, self.num_hparams), slice(0, self.num_seeds))

        def take(axis: int | None, leaf: jax.Array) -> jax.Array | np.ndarray:
            key_impl = jax.random.key_impl(leaf) if is_key(leaf) else None
            array = self._gather_leaf(leaf)
            array = array if axis is None else array[real]
            return array if key_impl is None else jax.random.wrap_key_data(array, impl=key_impl)

        return map_axes(take, axes, state)

    def gather(self, metrics: Tree) -> Tree:
        """Host copies of ``[H_padded, S_padded]`` outputs (chunk metrics, or any tree of such
        leaves), cut to ``[H, S]``."""
        real = (slice(0, self.num_hparams), slice(0, self.num_seeds))
        return jax.tree.map(lambda leaf: self._gather_leaf(leaf)[real], metrics)

    def _gather_leaf(self, leaf: jax.Array) -> np.ndarray:
        if self.multiprocess and not leaf.is_fully_addressable:
            if is_key(leaf):
                leaf = jax.random.key_data(leaf)
            return np.asarray(multihost_utils.process_allgather(leaf, tiled=True))
        return _host(leaf)

    def template(self, hparams: Hyperparams) -> TrainState:
        """``jax.ShapeDtypeStruct`` tree (with shardings) of the device state: nothing allocated."""
        axes = self.axes(hparams)
        abstract = one_run_shapes(self.algorithm, self.config, hparams)

        def grow(axis: int | None, leaf: jax.ShapeDtypeStruct) -> jax.ShapeDtypeStruct:
            if axis is None:
                return jax.ShapeDtypeStruct(
                    leaf.shape, leaf.dtype, sharding=self.sharding(PartitionSpec())
                )
            shape = (*self.padded, *leaf.shape)
            return jax.ShapeDtypeStruct(shape, leaf.dtype, sharding=self.sharding())

        return map_axes(grow, axes, abstract)

    def local_fraction(self) -> float:
        """Share of the state held by this process's devices (1 without ``jax.distributed``)."""
        local = sum(d.process_index == jax.process_index() for d in self.mesh.devices.flat)
        return local / self.layout.devices

    # ---- programs --------------------------------------------------------------------------

    def _wrap(self, function: Callable, in_specs: object, out_specs: object) -> Callable:
        """``shard_map`` over the mesh; on one device the vmapped function as it is (an MJX env
        step under a one-device ``shard_map`` runs many times slower)."""
        if self.layout.devices == 1:
            return function
        # check_vma=False: each device's block is an independent program; the replication check
        # would demand casts inside every learner's branches for no benefit.
        return jax.shard_map(
            function, mesh=self.mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False
        )

    def _build(self, hparams: Hyperparams) -> tuple[jax.stages.Wrapped, jax.stages.Wrapped]:
        """The jitted ``(init, chunk)``, shared by every ``Program`` of the same algorithm, config
        and layout in this process (a resumed or repeated run does not trace again)."""
        if self._key_impl is None:  # a restored state trains before any init: the default
            self._key_impl = jax.random.key_impl(jax.random.key(0))
        key = (
            self.algorithm,
            self.config,
            self.layout,
            self.loop_seeds,
            tuple(self.mesh.devices.flat),
            str(self._key_impl),
            jax.tree.structure(hparams),
        )
        if key not in _PROGRAMS:
            _PROGRAMS[key] = self._programs(hparams)
        self._init, self._chunk = _PROGRAMS[key]
        self._program_key = key
        return _PROGRAMS[key]

    def _programs(self, hparams: Hyperparams) -> tuple[jax.stages.Wrapped, jax.stages.Wrapped]:
        algorithm, config = self.algorithm, self.config
        axes = self.axes(hparams)
        state_specs = _specs(axes)
        runs, by_seed, by_hparam = (
            PartitionSpec(*AXES),
            PartitionSpec(AXES[1]),
            PartitionSpec(AXES[0]),
        )

        key_impl = self._key_impl

        def init_one(key_data: jax.Array, hp: Hyperparams) -> TrainState:
            return algorithm.init(jax.random.wrap_key_data(key_data, impl=key_impl), config, hp)

        init = jax.vmap(init_one, in_axes=(0, None), out_axes=axes)
        init = jax.vmap(init, in_axes=(None, 0), out_axes=axes)
        init = self._wrap(init, (by_seed, by_hparam), state_specs)
        init = jax.jit(init, out_shardings=self._shardings(state_specs))

        def chunk_one(state: TrainState, hp: Hyperparams) -> tuple[TrainState, ChunkMetrics]:
            return algorithm.train_chunk(state, config, hp)

        if self.loop_seeds:
            seeds_per_device = self.layout.padded_seeds // self.layout.seed_split
            chunk = seed_loop(chunk_one, axes, seeds_per_device)
        else:
            chunk = jax.vmap(chunk_one, in_axes=(axes, None), out_axes=(axes, 0))
        chunk = jax.vmap(chunk, in_axes=(axes, 0), out_axes=(axes, 0))
        chunk = self._wrap(chunk, (state_specs, by_hparam), (state_specs, runs))
        # The old state is dead after a chunk: donating it lets XLA update the replay buffer
        # in place instead of holding two copies.
        # Output shardings pinned: XLA may otherwise return a zero-size leaf replicated, and the
        # next call, compiled for the sharded input, would refuse it.
        out_shardings = (self._shardings(state_specs), self.sharding(runs))
        return init, jax.jit(chunk, donate_argnums=0, out_shardings=out_shardings)

    def _shardings(self, specs: TrainState) -> TrainState:
        return jax.tree.map(self.sharding, specs, is_leaf=lambda x: isinstance(x, PartitionSpec))

    def _placed(self, hparams: Hyperparams) -> Hyperparams:
        """``[H]`` hyperparameters padded and put on the mesh (memoized per object)."""
        if self._placed_hparams is None or self._placed_hparams[0] is not hparams:
            sizes = (self.layout.padded_hparams,)
            by_hparam = self.sharding(PartitionSpec(AXES[0]))
            placed = jax.tree.map(
                lambda x: self._put(_pad_edge(np.asarray(x), sizes), by_hparam), hparams
            )
            self._placed_hparams = (hparams, placed)
        return self._placed_hparams[1]

    def init(self, keys: jax.Array, hparams: Hyperparams) -> TrainState:
        """Fresh device state (``[H_padded, S_padded]`` leaves) from ``[S]`` keys and
        ``[H]``-stacked hyperparameters."""
        self._check(keys.shape[0], hparams)
        self._key_impl = jax.random.key_impl(keys)
        init = self._init if self._init is not None else self._build(hparams)[0]
        key_data = _pad_edge(_host(keys), (self.layout.padded_seeds,))
        placed_keys = self._put(key_data, self.sharding(PartitionSpec(AXES[1])))
        return init(placed_keys, self._placed(hparams))

    def train_chunk(
        self, state: TrainState, hparams: Hyperparams
    ) -> tuple[TrainState, ChunkMetrics]:
        """One chunk for every run (metrics leaves ``[H_padded, S_padded]``; ``gather`` cuts
        them). ``state`` is donated: use the returned one."""
        chunk = self._chunk if self._chunk is not None else self._build(hparams)[1]
        return chunk(state, self._placed(hparams))

    def compile(self, state: TrainState, hparams: Hyperparams) -> Chunk:
        """The chunk compiled ahead of time (to time compilation apart from training):
        ``compiled(state, hparams) -> (state, metrics)``."""
        chunk = self._chunk if self._chunk is not None else self._build(hparams)[1]
        key = self._program_key
        assert key is not None  # set by _build
        if key not in _COMPILED:
            lowered = chunk.lower(state, self._placed(hparams))
            _COMPILED[key] = lowered.compile()
        compiled = _COMPILED[key]
        return lambda state, hparams: compiled(state, self._placed(hparams))

    def select(self, state: TrainState, hparam_index: int, seed_index: int) -> TrainState:
        """One run's state (device or host state)."""
        return select(state, hparam_index, seed_index)

    def _check(self, num_keys: int, hparams: Hyperparams) -> None:
        sizes = {np.shape(leaf)[0] for leaf in jax.tree.leaves(hparams)}
        if num_keys != self.num_seeds or sizes != {self.num_hparams}:
            raise ValueError(
                f"expected {self.num_seeds} keys and hyperparameters stacked to "
                f"{self.num_hparams}, got {num_keys} keys and leading sizes {sorted(sizes)}"
            )
