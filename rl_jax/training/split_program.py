"""``[H, S]`` runs split unevenly over devices, without padding: each device its own block of
runs (5 seeds on 2 devices as 3 + 2; on 4 as 2 + 1 + 1 + 1), and one ``parallel.Program`` per
block size, whose mesh spans the devices of the blocks of that size (on 4 devices: 2 seeds on
the first, and 3 seeds sharded 1 + 1 + 1 over the other three).

A padded program (``parallel.Program``) computes copies of a run to make the runs divide; on CPU
devices of one process, which share the same cores, the copies take their share of them, and a
device left out of the mesh leaves its part of the host idle. A split computes the real runs
only, on every device, at the cost of a second compiled program (blocks as even as can be have
at most two sizes; XLA compiles a program once for all the devices of its mesh, but once per
device for programs on one device each). ``rl_jax.run.plan.program_for`` chooses between the
two.

The device state of a split is a tuple with one ``[h, s]`` state per group of blocks of one
size, as are its chunk metrics; ``gather``, ``unpad`` and ``place`` translate to and from the
``[H, S]`` runs that every saved file holds, so a checkpoint of a split run resumes on any
layout and the other way round. Each group computes its runs as that group's ``Program`` does:
a block of several seeds gives what the same seeds give in a bigger batch (the same kernels, on
the locked jaxlib), a block of one seed may round differently.

Usage (what ``parallel.Program`` offers)::

    program = SplitProgram(td3, config, num_hparams=1, num_seeds=5, devices=jax.devices())
    state = program.init(parallel.seed_keys(range(5)), hparams)
    state, metrics = program.train_chunk(state, hparams)
    metrics = program.gather(metrics)  # [1, 5] host arrays
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeAlias, cast

import jax
import jax.numpy as jnp
import numpy as np

from rl_jax.training import parallel
from rl_jax.training.algorithm import Algorithm, ChunkMetrics, Config, Hyperparams, TrainState
from rl_jax.training.device_layout import block_seeds_floor
from rl_jax.training.parallel import Tree

#: a split's state on the devices: one ``[h, s]`` train state per group of blocks of one size
#: (itself a train state: a tuple of them)
Blocks: TypeAlias = tuple[TrainState, ...]
#: a split's chunk metrics: one ``[h, s]`` tree per group, joined by ``SplitProgram.gather``
BlockMetrics: TypeAlias = tuple[ChunkMetrics, ...]
Leaf: TypeAlias = jax.Array | np.ndarray


@dataclasses.dataclass(frozen=True)
class Block:
    """The runs ``[hparams, seeds]`` of one device, as index ranges into the ``[H, S]`` grid."""

    hparams: range
    seeds: range

    @property
    def runs(self) -> int:
        """Runs of the block."""
        return len(self.hparams) * len(self.seeds)


@dataclasses.dataclass(frozen=True)
class Group:
    """Blocks of one size side by side: their runs together and the devices that hold them,
    one block each (one program, sharded evenly over those devices)."""

    runs: Block
    devices: range


@dataclasses.dataclass(frozen=True)
class SplitLayout:
    """Blocks of runs, one per device, split along one axis of the ``[H, S]`` grid (``axis`` 0:
    hyperparameter sets, 1: seeds). No run is computed twice."""

    num_hparams: int
    num_seeds: int
    axis: int
    sizes: tuple[int, ...]  # runs along ``axis`` per block, largest first

    @property
    def blocks(self) -> tuple[Block, ...]:
        """The blocks in device order, contiguous along ``axis``."""
        starts = np.cumsum((0, *self.sizes))
        ranges = [range(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:], strict=True)]
        if self.axis == 1:
            return tuple(Block(range(self.num_hparams), r) for r in ranges)
        return tuple(Block(r, range(self.num_seeds)) for r in ranges)

    @property
    def devices(self) -> int:
        """Devices used: one per block."""
        return len(self.sizes)

    @property
    def runs_per_device(self) -> int:
        """Runs of the busiest device."""
        return max(block.runs for block in self.blocks)

    @property
    def padding(self) -> int:
        """Extra runs computed: none."""
        return 0

    @property
    def padded_hparams(self) -> int:
        """Hyperparameter sets computed: the real ones."""
        return self.num_hparams

    @property
    def padded_seeds(self) -> int:
        """Seeds computed: the real ones."""
        return self.num_seeds

    @property
    def shapes(self) -> int:
        """Distinct block sizes: the programs compiled (one per group)."""
        return len(self.groups)

    @property
    def groups(self) -> tuple[Group, ...]:
        """The blocks of each size together (contiguous: sizes fall), with their devices."""
        groups: list[Group] = []
        start = 0
        for _, same in itertools.groupby(self.sizes):
            count = len(list(same))
            first, last = self.blocks[start], self.blocks[start + count - 1]
            if self.axis == 1:
                runs = Block(first.hparams, range(first.seeds.start, last.seeds.stop))
            else:
                runs = Block(range(first.hparams.start, last.hparams.stop), first.seeds)
            groups.append(Group(runs, range(start, start + count)))
            start += count
        return tuple(groups)


def split_layout(num_hparams: int, num_seeds: int, num_devices: int) -> SplitLayout:
    """Blocks as even as can be along the axis that leaves the busiest device the fewest runs
    (seeds on a tie): 5 seeds on 2 devices as 3 + 2; 3 sets x 1 seed as sets 2 + 1. A block of
    seeds holds ``device_layout.block_seeds_floor`` of them or more: 3 seeds on 2 devices stay
    one block of 3.
    """
    best: SplitLayout | None = None
    for axis, length in ((1, num_seeds), (0, num_hparams)):
        fewest = block_seeds_floor(num_seeds) if axis == 1 else 1
        used = max(1, min(length // fewest, num_devices))
        sizes = tuple(len(part) for part in np.array_split(np.arange(length), used))
        layout = SplitLayout(num_hparams, num_seeds, axis, sizes)
        if best is None or layout.runs_per_device < best.runs_per_device:
            best = layout
    assert best is not None
    return best


def blocks(state: TrainState) -> Blocks:
    """A split's device state as its groups' states (``Blocks`` is a kind of ``TrainState``)."""
    assert isinstance(state, tuple), "a split program's state is a tuple of group states"
    return cast(Blocks, state)


def _rows(array: Leaf, block: Block) -> Leaf:
    """The ``[h, s]`` runs of ``block`` of an ``[H, S]``-leading array (typed keys included)."""
    rows = array[block.hparams.start : block.hparams.stop]
    return rows[:, block.seeds.start : block.seeds.stop]


class SplitProgram:
    """``parallel.Program``'s interface over an uneven split of the runs: a ``Program`` per
    group of blocks of one size, on the devices of those blocks (one process; a mesh over
    processes needs equal blocks)."""

    def __init__(
        self,
        algorithm: Algorithm,
        config: Config,
        num_hparams: int,
        num_seeds: int,
        devices: Sequence[jax.Device],
        loop_seeds: bool = False,
    ):
        self.algorithm, self.config = algorithm, config
        self.num_hparams, self.num_seeds = num_hparams, num_seeds
        self.layout = split_layout(num_hparams, num_seeds, len(devices))
        self.devices = list(devices)[: self.layout.devices]
        self.groups = self.layout.groups
        self.programs = [
            parallel.Program(
                algorithm,
                config,
                len(group.runs.hparams),
                len(group.runs.seeds),
                devices=[self.devices[index] for index in group.devices],
                pad=False,
                loop_seeds=loop_seeds,
            )
            for group in self.groups
        ]
        for program, group in zip(self.programs, self.groups, strict=True):
            # equal blocks divide evenly: the group's program uses each of its devices
            assert program.layout.devices == len(group.devices), (program.layout, group)
        self._hparams: tuple[Hyperparams, list[Hyperparams]] | None = None

    @property
    def padded(self) -> tuple[int, int]:
        """``(hyperparameter sets, seeds)`` computed: the real runs, no padding."""
        return self.num_hparams, self.num_seeds

    def _split_hparams(self, hparams: Hyperparams) -> list[Hyperparams]:
        """Each group's ``[h]`` hyperparameters (memoized per object, so that each group's
        program keeps its placed copy)."""
        if self._hparams is None or self._hparams[0] is not hparams:
            parts = [
                jax.tree.map(
                    lambda x, b=group.runs: np.asarray(x)[b.hparams.start : b.hparams.stop],
                    hparams,
                )
                for group in self.groups
            ]
            self._hparams = (hparams, parts)
        return self._hparams[1]

    def axes(self, hparams: Hyperparams) -> parallel.Axes:
        """vmap axes of the state (0, or ``None`` for the shared clock)."""
        return self.programs[0].axes(self._split_hparams(hparams)[0])

    # ---- programs --------------------------------------------------------------------------

    def init(self, keys: jax.Array, hparams: Hyperparams) -> Blocks:
        """Each group's fresh state from its seeds' keys."""
        parts = self._split_hparams(hparams)
        return tuple(
            program.init(keys[group.runs.seeds.start : group.runs.seeds.stop], part)
            for program, group, part in zip(self.programs, self.groups, parts, strict=True)
        )

    def _dispatch(
        self, chunks: Sequence[parallel.Chunk], state: TrainState, hparams: Hyperparams
    ) -> tuple[Blocks, BlockMetrics]:
        """Each group's chunk on its state, each dispatched before any is waited for."""
        parts = self._split_hparams(hparams)
        done = [
            chunk(block_state, part)
            for chunk, block_state, part in zip(chunks, blocks(state), parts, strict=True)
        ]
        return tuple(new for new, _ in done), tuple(metrics for _, metrics in done)

    def train_chunk(self, state: TrainState, hparams: Hyperparams) -> tuple[Blocks, BlockMetrics]:
        """One chunk of every run (``state`` is donated: use the returned one)."""
        return self._dispatch([program.train_chunk for program in self.programs], state, hparams)

    def compile(
        self, state: TrainState, hparams: Hyperparams
    ) -> Callable[[TrainState, Hyperparams], tuple[Blocks, BlockMetrics]]:
        """Every group's chunk compiled ahead of time, in threads (XLA compiles outside the
        interpreter lock): ``compiled(state, hparams) -> (state, metrics)``."""
        parts = self._split_hparams(hparams)
        jobs = list(zip(self.programs, blocks(state), parts, strict=True))
        with ThreadPoolExecutor(len(jobs)) as pool:
            chunks = list(pool.map(lambda job: job[0].compile(job[1], job[2]), jobs))

        return lambda state, hparams: self._dispatch(chunks, state, hparams)

    # ---- to and from the [H, S] runs -------------------------------------------------------

    def gather_each(self, function: Callable[[TrainState], Tree], state: TrainState) -> Tree:
        """``function`` of each group's device state (``[h, s]``-leading outputs), joined into
        host ``[H, S]`` copies."""
        return self.gather(tuple(function(group_state) for group_state in blocks(state)))

    def _join(self, parts: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(parts, axis=self.layout.axis)

    def gather(self, trees: tuple[Tree, ...]) -> Tree:
        """Host ``[H, S]`` copies of per-group ``[h, s]`` outputs (chunk metrics)."""
        gathered = [
            program.gather(tree) for program, tree in zip(self.programs, trees, strict=True)
        ]
        return jax.tree.map(lambda *parts: self._join(list(parts)), *gathered)

    def unpad(self, state: TrainState, hparams: Hyperparams) -> TrainState:
        """The ``[H, S]`` runs as host arrays (typed keys stay keys; the clock is one)."""
        parts = self._split_hparams(hparams)
        hosts = [
            program.unpad(group_state, part)
            for program, group_state, part in zip(self.programs, blocks(state), parts, strict=True)
        ]

        def join(axis: int | None, *leaves: Leaf) -> Leaf:
            if axis is None:
                return leaves[0]
            if parallel.is_key(leaves[0]):  # typed keys join as keys (numpy has no such dtype)
                return jnp.concatenate(leaves, axis=self.layout.axis)
            return self._join([np.asarray(leaf) for leaf in leaves])

        axes = self.axes(hparams)
        return jax.tree.map(
            lambda axis, *subtrees: jax.tree.map(lambda *leaves: join(axis, *leaves), *subtrees),
            axes,
            *hosts,
            is_leaf=lambda x: x is None,
        )

    def place(self, state: TrainState, hparams: Hyperparams) -> Blocks:
        """An ``[H, S]`` state (a restored checkpoint) split into groups on their devices."""
        axes = self.axes(hparams)
        parts = self._split_hparams(hparams)
        placed = []
        for program, group, part in zip(self.programs, self.groups, parts, strict=True):

            def take(axis: int | None, leaf: Leaf, runs: Block = group.runs) -> Leaf:
                return leaf if axis is None else _rows(leaf, runs)

            placed.append(program.place(parallel.map_axes(take, axes, state), part))
        return tuple(placed)

    def template(self, hparams: Hyperparams) -> TrainState:
        """Shapes of the state on the devices, all groups together (``[H, S]``: no padding)."""
        runs = (self.num_hparams, self.num_seeds)
        group_template = self.programs[0].template(self._split_hparams(hparams)[0])
        return parallel.map_axes(
            lambda axis, leaf: (
                jax.ShapeDtypeStruct(leaf.shape, leaf.dtype)
                if axis is None
                else jax.ShapeDtypeStruct((*runs, *leaf.shape[2:]), leaf.dtype)
            ),
            self.axes(hparams),
            group_template,
        )

    def select(self, state: TrainState, hparam_index: int, seed_index: int) -> TrainState:
        """One run's state out of an ``[H, S]`` (host) state."""
        return parallel.select(state, hparam_index, seed_index)

    def local_fraction(self) -> float:
        """Share of the state this process holds: all of it (a split is one process's)."""
        return 1.0
