"""How the ``[H, S]`` runs of a program (hyperparameter sets x seeds) are split over devices:
the mesh's shape, the padding that makes the runs split evenly, and the mesh itself.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import numpy as np
from jax.sharding import Mesh

AXES = ("hparams", "seeds")
#: The fewest seeds of a run's configuration a device computes together, once a run has that
#: many: XLA compiles a vmap over one seed to other kernels than a vmap over several (its size-1
#: axis folds away), which round differently, while blocks of 2, 3 or 5 seeds give the same
#: numbers bit for bit on the locked jaxlib. With every block of a run at 2 seeds or more, a
#: seed's numbers are the same in every layout of one command (1 device or many, 1 process or
#: many, padded or split); a seed run alone (``--seeds 1``) is a block of one, and rounds
#: otherwise.
MIN_BLOCK_SEEDS = 2


def block_seeds_floor(num_seeds: int) -> int:
    """The fewest seeds any device's block of ``num_seeds`` seeds may hold (``MIN_BLOCK_SEEDS``,
    or all of them when there are fewer)."""
    return min(MIN_BLOCK_SEEDS, num_seeds)


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


@dataclasses.dataclass(frozen=True)
class Layout:
    """How ``[H, S]`` runs sit on a ``(hparam_split, seed_split)`` device mesh.

    When the runs do not split evenly, an axis is padded to a multiple of its split with copies
    of its first run (seed 0, hyperparameter set 0); the copies compute alongside and are dropped
    from everything reported. 5 seeds on 2 devices run as 3 + 3 instead of 5 on one device.
    """

    num_hparams: int
    num_seeds: int
    hparam_split: int = 1
    seed_split: int = 1

    @property
    def padded_hparams(self) -> int:
        """Hyperparameter sets after padding to a multiple of ``hparam_split``."""
        return -(-self.num_hparams // self.hparam_split) * self.hparam_split

    @property
    def padded_seeds(self) -> int:
        """Seeds after padding to a multiple of ``seed_split``."""
        return -(-self.num_seeds // self.seed_split) * self.seed_split

    @property
    def devices(self) -> int:
        """Devices of the mesh."""
        return self.hparam_split * self.seed_split

    @property
    def runs_per_device(self) -> int:
        """Runs (padding included) each device computes."""
        return self.padded_hparams * self.padded_seeds // self.devices

    @property
    def padding(self) -> int:
        """Extra runs computed and dropped."""
        return self.padded_hparams * self.padded_seeds - self.num_hparams * self.num_seeds


def plan_layout(
    num_hparams: int, num_seeds: int, num_devices: int, pad: bool = True, min_devices: int = 1
) -> Layout:
    """The mesh for ``[H, S]`` runs on up to ``num_devices`` devices.

    Without padding: ``mesh_shape``. With padding: among the layouts whose every block holds
    ``block_seeds_floor`` seeds or more (so that a seed's numbers do not depend on the layout),
    the fewest runs per device (the wall-clock of a chunk), then the fewest padded runs
    (memory), then the fewest devices, then seeds split before hyperparameters. A single run
    stays on one device, unless ``min_devices`` asks for more: a mesh over several processes
    uses every device, so that no process's devices sit idle while it takes part in every call,
    padding where it must.
    """
    if not pad:
        return Layout(num_hparams, num_seeds, *mesh_shape(num_hparams, num_seeds, num_devices))
    candidates = []
    for used in range(min(max(min_devices, 1), num_devices), num_devices + 1):
        for seed_split in range(1, used + 1):
            if used % seed_split:
                continue
            layout = Layout(num_hparams, num_seeds, used // seed_split, seed_split)
            if layout.padded_seeds // seed_split < block_seeds_floor(num_seeds):
                continue
            total = layout.padded_hparams * layout.padded_seeds
            candidates.append(((layout.runs_per_device, total, used, -seed_split), layout))
    return min(candidates, key=lambda candidate: candidate[0])[1]


def make_mesh(
    num_hparams: int, num_seeds: int, devices: Sequence[jax.Device] | None = None
) -> Mesh:
    """A ``("hparams", "seeds")`` device mesh shaped by ``mesh_shape`` (no padding)."""
    devices = list(jax.devices() if devices is None else devices)
    hparam_split, seed_split = mesh_shape(num_hparams, num_seeds, len(devices))
    used = np.array(devices[: hparam_split * seed_split]).reshape(hparam_split, seed_split)
    return Mesh(used, AXES)
