"""SAC's update beside SBX's SAC at equal work (``python -m bench peers_sac``): the cases,
layouts and timing of ``bench_peers`` (TD3's comparison), with our SAC and ``sbx.SAC``.

* **Ours**: ``rl_jax.agents.sac`` with the case's networks for actor and both critics, 5 seeds
  as one compiled program, 4 envs per seed with 4 updates per iteration (one update per env
  step), on 1 device and on 2 (3 + 3), timed over whole training chunks, before and after SBX.
* **SBX** (``bench/sbx_sac.py``): ``sbx.SAC`` with the same ``net_arch`` and batch,
  ``train_freq=1, gradient_steps=1``, ``policy_delay=1`` and the learned temperature
  (``ent_coef="auto"``, target entropy -|A|), as two processes at once, one per core.

Both do the paper's update: a critic step, then an actor step and a temperature step, every env
step. MFLOP/update are the matmuls of our traced update (``bench.sac_programs.update_flops``):
the critic step runs the actor forward on s' besides the twin (target) critics, and the actor
step, every update (TD3's every second), backpropagates through both critics' minimum. So a SAC
update costs ~1.4x TD3's at the same sizes (half cheetah 256 x 256, batch 256: 581.6 against
414.6 MFLOP), and updates/s are compared at these equal FLOPs per update.
"""

from __future__ import annotations

from bench.bench_peers import report

TITLE = "SAC: ours beside SBX's SAC at equal work"


def run(quick: bool = False) -> str:
    """The Markdown section (``bench_peers.report`` for SAC)."""
    return report(quick, "sac", TITLE, "peers_sac")
