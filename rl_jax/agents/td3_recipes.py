"""TD3's and DDPG's recipes (``rl_jax.training.recipes``): each env's default on top of the
paper's settings (the ``Config``/``Hyperparams`` defaults), and named alternatives, each with the
reason it was chosen. How they were chosen: docs/learners/td3.md#how-the-recipes-were-chosen.
"""

from __future__ import annotations

from rl_jax.training.recipes import Recipe, Recipes, Setting

# The classic envs: small networks suffice, one update per env step as in the paper.
PENDULUM_CONFIG: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 250,
    "learning_starts": 1000,
    "actor_hidden": (64, 64),
    "critic_hidden": (64, 64),
}
# The rocket and its settle variant: the Pendulum loop with 5,000-step chunks (10 episodes).
ROCKET_CONFIG: dict[str, Setting] = {
    **PENDULUM_CONFIG,
    "iterations_per_chunk": 1250,
    "learning_starts": 2000,
}
# Rocket: a longer horizon, and exploration noise that pushes long enough to move the velocity
# (docs/learners/td3.md#how-the-recipes-were-chosen).
ROCKET_HPARAMS: dict[str, float] = {
    "gamma": 0.995,
    "exploration_correlation": 0.98,
    "exploration_noise": 0.5,
}
# Half cheetah's CPU loop: one update per env step, cheaper ones, since on a CPU updates are the
# cost (docs/learners/td3.md#how-the-recipes-were-chosen).
CHEETAH_LOOP: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 1250,  # eval every 5,000 env steps per seed
    "batch_size": 128,
    "learning_starts": 10_000,
}
# Half cheetah's default: 128 x 128 at rate 1e-3, chosen by return against wall-clock
# (RESULTS.md#td3-on-half-cheetah-in-minutes).
FAST_CHEETAH_CONFIG: dict[str, Setting] = {"actor_hidden": (128, 128), "critic_hidden": (128, 128)}
FAST_CHEETAH_HPARAMS: dict[str, float] = {"actor_lr": 1e-3, "critic_lr": 1e-3}
# The rest of the MuJoCo suite runs half cheetah's recipe unchanged, so that the suite's results
# say what one recipe does on each task.
CHEETAH_CPU_CONFIG: dict[str, Setting] = {**CHEETAH_LOOP, **FAST_CHEETAH_CONFIG}
MUJOCO_SUITE = tuple(
    f"rl_jax/{name}-v5" for name in ("Hopper", "Walker2d", "Ant", "Reacher", "Swimmer", "Humanoid")
)
# Humanoid: raw contact forces beside joint angles saturate the actor's tanh unless standardised.
HUMANOID_CONFIG: dict[str, Setting] = {**CHEETAH_CPU_CONFIG, "normalize_obs": True}
#: The per-env config settings above, by env id (what each env's ``default`` recipe starts from).
RECIPES: dict[str, dict[str, Setting]] = {
    "rl_jax/Pendulum-v1": PENDULUM_CONFIG,
    "rl_jax/Rocket-v0": ROCKET_CONFIG,
    "rl_jax/RocketSettle-v0": ROCKET_CONFIG,
    "rl_jax/HalfCheetah-v5": CHEETAH_LOOP,
    **{env_id: CHEETAH_CPU_CONFIG for env_id in MUJOCO_SUITE if env_id != "rl_jax/Humanoid-v5"},
    "rl_jax/Humanoid-v5": HUMANOID_CONFIG,
}
# The TD3 paper's own loop: one env, one update per env step, batch 256, 25k warm-up steps.
PAPER_CONFIG: dict[str, Setting] = {
    "num_envs": 1,
    "updates_per_iteration": 1,
    "iterations_per_chunk": 5000,
    "batch_size": 256,
    "learning_starts": 25_000,
}
# The TD3 paper's whole recipe on any env: its loop above, its 256 x 256 networks and its rates
# (the Config and Hyperparams defaults, restated because the MuJoCo suite's recipes change them).
PAPER_RECIPE_CONFIG: dict[str, Setting] = {
    **PAPER_CONFIG,
    "actor_hidden": (256, 256),
    "critic_hidden": (256, 256),
}
PAPER_HPARAMS: dict[str, Setting] = {"actor_lr": 3e-4, "critic_lr": 3e-4}
# The settings of the TD3 paper's own runs (2018), which made the curves our results compare with
# (RESULTS.md#two-paper-recipes-on-hopper); 10,000 random steps on PAPER_2018_LONG_WARMUP.
PAPER_2018_CONFIG: dict[str, Setting] = {
    **PAPER_CONFIG,
    "batch_size": 100,
    "learning_starts": 1_000,
    "actor_hidden": (400, 300),
    "critic_hidden": (400, 300),
}
PAPER_2018_HPARAMS: dict[str, Setting] = {"actor_lr": 1e-3, "critic_lr": 1e-3}
# Half cheetah on one GPU (MJX), where more envs and larger batches cost little more time; chosen
# by return against wall-clock (docs/learners/td3.md#how-the-recipes-were-chosen).
GPU_CHEETAH_CONFIG: dict[str, Setting] = {
    **FAST_CHEETAH_CONFIG,
    "num_envs": 64,
    "batch_size": 1024,
    "updates_per_iteration": 32,
    "iterations_per_chunk": 384,  # 24,576 env steps per seed between evaluations
    "buffer_size": 500_000,
}
PAPER_2018_LONG_WARMUP = ("rl_jax/HalfCheetah-v5", "rl_jax/Ant-v5")
CHEETAH = "rl_jax/HalfCheetah-v5"
# The inverted double pendulum: one update per env step in 4 envs, the paper's evaluation interval.
_DOUBLE_PENDULUM = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 1_250,
    "learning_starts": 10_000,
    "buffer_size": 200_000,  # the whole run (x seeds) fits in memory with room to spare
}

#: TD3's recipes (DDPG's too: its own defaults differ, its recipes are these).
TD3_RECIPES = Recipes(
    Recipe(
        "default",
        "64x64 networks, 4 envs x 4 updates per iteration",
        PENDULUM_CONFIG,
        envs=("rl_jax/Pendulum-v1",),
        # measured: docs/learners/td3.md#how-the-recipes-were-chosen (as every throughput below)
        throughput=(830.0, 5),
    ),
    Recipe(
        "default",
        "the Pendulum loop, gamma 0.995, AR(1) exploration noise (rho 0.98, std 0.5)",
        {**ROCKET_CONFIG, "iterations_per_chunk": 625},
        ROCKET_HPARAMS,
        envs=("rl_jax/Rocket-v0", "rl_jax/RocketSettle-v0"),
    ),
    Recipe(
        "default",
        "the paper's networks, 4 envs x 4 updates per iteration, 10,000 warm-up steps",
        _DOUBLE_PENDULUM,
        envs=("rl_jax/InvertedDoublePendulum-v5",),
    ),
    Recipe(
        "default",
        "128x128 at rate 1e-3, batch 128, 4 envs x 4 updates, 10,000 warm-up steps",
        CHEETAH_CPU_CONFIG,
        FAST_CHEETAH_HPARAMS,
        envs=(CHEETAH,),
        throughput=(280.0, 5),
    ),
    Recipe(
        "default",
        "half cheetah's CPU recipe: 128x128 at rate 1e-3, batch 128, 4 envs x 4 updates",
        CHEETAH_CPU_CONFIG,
        FAST_CHEETAH_HPARAMS,
        envs=tuple(env_id for env_id in MUJOCO_SUITE if env_id != "rl_jax/Humanoid-v5"),
    ),
    Recipe(
        "default",
        "half cheetah's CPU recipe, observations standardised by running statistics",
        HUMANOID_CONFIG,
        FAST_CHEETAH_HPARAMS,
        envs=("rl_jax/Humanoid-v5",),
    ),
    Recipe(
        "paper-width",
        "the paper's 256x256 networks at rate 3e-4 in the CPU loop",
        CHEETAH_LOOP,
        envs=(CHEETAH,),
        throughput=(96.0, 5),
    ),
    Recipe(
        "paper",
        "the TD3 repository's recipe since 2019: 256x256 at rate 3e-4, one env, batch 256, "
        "25,000 warm-up steps",
        PAPER_RECIPE_CONFIG,
        PAPER_HPARAMS,
    ),
    Recipe(
        "paper-2018",
        "the settings of the TD3 paper's own runs: 400x300 at rate 1e-3, one env, batch 100, "
        "1,000 warm-up steps",
        PAPER_2018_CONFIG,
        PAPER_2018_HPARAMS,
    ),
    Recipe(
        "paper-2018",
        "the settings of the TD3 paper's own runs: 400x300 at rate 1e-3, one env, batch 100, "
        "10,000 warm-up steps",
        {**PAPER_2018_CONFIG, "learning_starts": 10_000},
        PAPER_2018_HPARAMS,
        envs=PAPER_2018_LONG_WARMUP,
    ),
    Recipe(
        "gpu",
        "for one GPU (MJX): 64 envs per seed, batch 1,024, 32 updates per iteration",
        {**CHEETAH_LOOP, **GPU_CHEETAH_CONFIG},
        FAST_CHEETAH_HPARAMS,
        envs=(CHEETAH,),
        total_steps=250_000,
    ),
)
