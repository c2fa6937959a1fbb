"""TD3 on rl_jax/HalfCheetah-v5 (MuJoCo half cheetah), all seeds as one compiled program.

The `make train` job. The learner is the TD3 paper's (Fujimoto et al. 2018): twin critics, one
gradient update per env step, policy delay 2, target smoothing 0.2 (clip 0.5), exploration noise
0.1. The default recipe is cut for a CPU, where updates cost far more than MuJoCo C env steps, and
chosen by return against wall-clock (`td3.FAST_CHEETAH_*`, BENCHMARKS.md "Half cheetah in
minutes"): 128x128 actor and critics at learning rate 1e-3, batch 128, 4 envs per seed with 4
updates per iteration, 10,000 random warm-up steps. With 5 seeds on a quiet 2-core CPU the mean
eval return passed 5,000 at 90,000 env steps, 5 minutes in; the default budget of 150,000 steps
takes about 9 minutes (RESULTS.md, row td3-cheetah).

The paper's networks and its whole recipe are --recipe paper-width and --recipe paper (below;
the TD3 repository's settings since 2019), and --recipe paper-2018 the settings of the paper's
own runs (400x300 at rate 1e-3, batch 100), which made its published learning curves;
--recipe td7 is TD7 (Fujimoto et al. 2023) as TD3's options: SALE, LAP, hard target copies,
value clipping and policy checkpoints on the paper's loop (td3.TD7_CONFIG). Its update costs 6.4x
TD3's arithmetic, about 8 hours for 5 seeds x 300,000 steps on 2 cores; --recipe td7-cpu runs the
same options in this script's CPU loop at 128 sizes (RESULTS.md, row td7-cpu-cheetah).
--recipe gpu is for one GPU, where MJX is the default backend: 64 envs per seed, batch 1,024 and
32 updates per iteration; on one H100, 5 seeds passed a mean of 5,000 after 53 s of training
(BENCHMARKS.md, "TD3 on a GPU").

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

from rl_jax.agents import td3 as td3_module
from rl_jax.agents.td3 import td3
from rl_jax.run.script import Recipe, Script

SCRIPT = Script(
    td3,
    "rl_jax/HalfCheetah-v5",  # the loop as it stands in td3.RECIPES
    seeds=5,  # `make train` passes --seeds 5 as well
    total_steps=150_000,  # env steps per seed: ~9 minutes for 5 seeds on a quiet machine
    config=td3_module.FAST_CHEETAH_CONFIG,
    hparams=td3_module.FAST_CHEETAH_HPARAMS,
    # (env steps/s per seed, seeds) with these defaults: 5 seeds, 150,000 steps in 8:56 with
    # compilation and evaluations (2 cores, load ~1.9). The plan's time estimate before the
    # first chunk; after it, the measured rate takes over.
    throughput=(280.0, 5),
    recipes={
        "paper-width": Recipe(
            "the paper's 256x256 networks at rate 3e-4 in the same CPU loop (mean 5,000 at "
            "~125k steps, 21 minutes for 5 seeds)",
            # RESULTS.md's earlier td3-cheetah row: 150,000 steps in 25:59 = 96 per seed.
            throughput=(96.0, 5),
        ),
        "paper": Recipe(
            "the TD3 repository's whole recipe since 2019: 256x256 at rate 3e-4, one env, batch "
            "256, 25,000 warm-up steps (the paper trains 1,000,000 steps: several hours here)",
            config=td3_module.PAPER_RECIPE_CONFIG,
            hparams=td3_module.PAPER_HPARAMS,
        ),
        "paper-2018": Recipe(
            "the settings of the TD3 paper's own runs (its published learning curves): 400x300 "
            "at rate 1e-3, one env, batch 100, 10,000 warm-up steps",
            config={
                **td3_module.PAPER_2018_CONFIG,
                **td3_module.NAMED_RECIPE_ENVS["paper-2018"]["rl_jax/HalfCheetah-v5"],
            },
            hparams=td3_module.PAPER_2018_HPARAMS,
        ),
        "td7": Recipe(
            "TD7 (Fujimoto et al. 2023) from TD3's options: the paper's loop with SALE, LAP, "
            "hard target copies every 250 updates, value clipping, policy checkpoints and ELU "
            "critics at rate 3e-4 (TD7's published settings; ~8 hours for 5 seeds x 300,000 steps "
            "on 2 cores)",
            config=td3_module.TD7_CONFIG,
            hparams=td3_module.TD7_HPARAMS,
        ),
        "gpu": Recipe(
            "for one GPU (MJX): 64 envs per seed, batch 1,024, 32 updates per iteration, 250,000 "
            "steps; on one H100 5 seeds passed a mean of 5,000 after 53 s of training "
            "(BENCHMARKS.md, TD3 on a GPU)",
            config=td3_module.GPU_CHEETAH_CONFIG,
            hparams=td3_module.FAST_CHEETAH_HPARAMS,
            total_steps=250_000,
        ),
        "td7-cpu": Recipe(
            "TD7's options in this script's CPU loop at its sizes: 128x128 networks, 128-d "
            "embeddings, TD7's rates 3e-4 (5 seeds x 300,000 steps in about 80 minutes)",
            config=td3_module.TD7_CPU_CONFIG,
            hparams=td3_module.TD7_CPU_HPARAMS,
            throughput=(61.0, 5),
        ),
    },
)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
