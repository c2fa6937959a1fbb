"""TD3 on rl_jax/HalfCheetah-v5 (MuJoCo half cheetah), all seeds as one compiled program.

The `make train` job. The learner is the TD3 paper's (Fujimoto et al. 2018): 256x256 actor and
twin critics, one gradient update per env step, policy delay 2, target smoothing 0.2 (clip 0.5),
exploration noise 0.1. The recipe (`td3.RECIPES`, measured in BENCHMARKS.md) is cut for a CPU,
where updates cost far more than MuJoCo C env steps: batch 128 (the paper's own code used 100),
4 envs per seed with 4 updates per iteration, 10,000 random warm-up steps. The default budget,
150,000 env steps per seed, took 26 minutes for 5 seeds on a quiet 2-core CPU and ended at a mean
eval return of 5,278 (RESULTS.md, row td3-cheetah). The paper trains for 1,000,000
steps with batch 256 (`--total-steps 1000000 --batch-size 256`, about 7 hours here).

It prints its plan (envs, steps, memory, devices, estimated time) before it starts, then a
progress bar (env steps/s, updates/s, ETA, latest eval return over seeds). Ctrl-C or SIGTERM
finishes the current chunk, writes a checkpoint and prints the command that resumes the run.

examples:
  python experiments/td3_cheetah.py --seeds 5
  python experiments/td3_cheetah.py --seeds 2 --total-steps 50000 --out runs/cheetah --gif
  python experiments/td3_cheetah.py --resume runs/cheetah --total-steps 100000
"""

from rl_jax.agents.td3 import td3
from rl_jax.run import cli

SCRIPT = cli.Script(
    td3,
    "rl_jax/HalfCheetah-v5",  # the recipe as it stands in td3.RECIPES
    seeds=5,  # `make train` passes --seeds 5 as well
    total_steps=150_000,  # env steps per seed: ~26 minutes for 5 seeds on a quiet machine
    # (env steps/s per seed, seeds) measured with this recipe on the 2-core machine: the
    # td3-cheetah row of RESULTS.md (5 seeds, 150,000 steps in 25:59 with compilation and
    # evaluations, load 1.5-2.1) is 96 per seed. The plan's time estimate before the first
    # chunk; after it, the measured rate takes over.
    throughput=(96.0, 5),
)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
