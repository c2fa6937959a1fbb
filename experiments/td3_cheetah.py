"""TD3 on rl_jax/HalfCheetah-v5 (MuJoCo half cheetah), all seeds as one compiled program.

The `make train` job. The learner is the TD3 paper's (Fujimoto et al. 2018): twin critics, one
gradient update per env step, policy delay 2, target smoothing 0.2 (clip 0.5), exploration noise
0.1. The default recipe is cut for a CPU, where updates cost far more than MuJoCo C env steps, and
chosen by return against wall-clock (td3's recipe for the env): 128x128 actor and critics at
learning rate 1e-3, batch 128, 4 envs per seed with 4 updates per iteration, 10,000 random
warm-up steps. The default budget is 150,000 env steps per seed.

The paper's networks and its whole recipe are --recipe paper-width and --recipe paper (below;
the TD3 repository's settings since 2019), and --recipe paper-2018 the settings of the paper's
own runs (400x300 at rate 1e-3, batch 100), which made its published learning curves;
--recipe td7 is TD7 (Fujimoto et al. 2023) as TD3's options: SALE, LAP, hard target copies,
value clipping and policy checkpoints on the paper's loop. Its update costs 6.4x
TD3's arithmetic (SALE's encoders), too much for a 2-core CPU; --recipe td7-cpu runs the
same options in this script's CPU loop at 128 sizes.
--recipe gpu is for one GPU, where MJX is the default backend: 64 envs per seed, batch 1,024 and
32 updates per iteration.

It prints its plan (envs, steps, memory, devices, estimated time) before it starts, then a
progress bar (env steps/s, updates/s, ETA, latest eval return over seeds). Ctrl-C or SIGTERM
finishes the current chunk, writes a checkpoint and prints the command that resumes the run.

examples:
  python experiments/td3_cheetah.py --seeds 5
  python experiments/td3_cheetah.py --seeds 2 --total-steps 50000 --out runs/cheetah --gif
  python experiments/td3_cheetah.py --recipe paper-width --seeds 5
  python experiments/td3_cheetah.py --recipe td7-cpu --seeds 5 --total-steps 300000
  python experiments/td3_cheetah.py --recipe gpu --seeds 5   # on a GPU
  python experiments/td3_cheetah.py --resume runs/cheetah --total-steps 300000
"""

from rl_jax.agents.td3 import td3
from rl_jax.run.script import Script

# the budget of `make train`, which passes --seeds 5
SCRIPT = Script(td3, "rl_jax/HalfCheetah-v5", seeds=5, total_steps=150_000)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
