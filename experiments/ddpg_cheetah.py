"""DDPG on rl_jax/HalfCheetah-v5 (MuJoCo half cheetah), all seeds as one compiled program.

The TD3 paper's "our DDPG" baseline (Fujimoto et al. 2018): TD3's code path with one critic, no
policy delay and no target policy smoothing; 256x256 networks, batch 256, one update per env
step, exploration noise 0.1. Compare it with experiments/td3_cheetah.py at the same budget (the
defaults match) to see what clipped double Q, delayed updates and smoothing buy.

It prints its plan (envs, steps, memory, devices, estimated time) before it starts, then a
progress bar (env steps/s, updates/s, ETA, latest eval return over seeds). Ctrl-C or SIGTERM
finishes the current chunk, writes a checkpoint and prints the command that resumes the run.

examples:
  python experiments/ddpg_cheetah.py --seeds 5
  python experiments/ddpg_cheetah.py --seeds 2 --total-steps 50000 --out runs/ddpg --gif
  python experiments/ddpg_cheetah.py --resume runs/ddpg
"""

import dataclasses

import td3_cheetah

from rl_jax.agents.td3 import ddpg

# The same budget and loop as the TD3 script, so the two compare like for like; the settings
# that make TD3 what it is stay DDPG's. One critic and an actor update per critic update run
# about as fast as TD3's two critics with the actor every second step, so the TD3 script's
# measured throughput serves for the estimate.
SCRIPT = dataclasses.replace(td3_cheetah.SCRIPT, algorithm=ddpg)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
