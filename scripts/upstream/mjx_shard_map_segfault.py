"""The smallest program we found that crashes jax 0.11.2 (SIGSEGV while XLA compiles it).

One MJX step of a one-hinge model, vmapped over 2 envs per device, under ``jax.shard_map`` over
2 CPU devices. Measured 2026-11-26 on a 2-core AMD EPYC, Python 3.12, mujoco / mujoco-mjx
4.0.0 / 3.17.0, fresh compilation cache (``JAX_COMPILATION_CACHE_DIR=``):

- jax 0.11.2: exit 139 (segmentation fault in ``backend_compile_and_load``), with
  ``check_vma`` off or on (``python mjx_shard_map_segfault.py vma``);
- jax 0.11.2 with 1 device (``--xla_force_host_platform_device_count=1``): runs;
- jax 0.9.2 (our pin) and 0.12.0.1 (the newest release): run and print 2.0.

It is how ``experiments/td3_cheetah.py`` on the MJX backend died on 2 CPU devices with jax 0.11.2
(``RL_JAX_MUJOCO_BACKEND=mjx RL_JAX_CPU_DEVICES=2``): the training program is shard_mapped over
the devices the same way. The bug is upstream (XLA's CPU compiler in jaxlib 0.11.2) and gone in
0.12; nothing in rl_jax is involved here, only jax and mujoco-mjx.

    python scripts/upstream/mjx_shard_map_segfault.py; echo $?
"""

import os
import sys

os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
from jax.sharding import Mesh, PartitionSpec  # noqa: E402
from mujoco import mjx  # noqa: E402

XML = """<mujoco><worldbody><body><joint name="j" type="hinge"/><geom size=".1" mass="1"/></body>
</worldbody><actuator><motor joint="j"/></actuator></mujoco>"""
model = mjx.put_model(mujoco.MjModel.from_xml_string(XML))
mesh = Mesh(jax.devices(), ("d",))


def step(ctrl):  # [envs on this device, 1] -> their joint velocities after one step
    data = jax.vmap(lambda c: mjx.make_data(model).replace(ctrl=c))(ctrl)
    return jax.vmap(mjx.step, in_axes=(None, 0))(model, data).qvel


sharded = jax.shard_map(
    step,
    mesh=mesh,
    in_specs=PartitionSpec("d"),
    out_specs=PartitionSpec("d"),
    check_vma=sys.argv[1:] == ["vma"],
)
print(jax.__version__, float(jax.jit(sharded)(jnp.ones((4, 1))).sum()), flush=True)
