"""SAC's recipes (``rl_jax.training.recipes``): each env's default on top of the paper's settings
(the ``Config``/``Hyperparams`` defaults), and the named alternatives: the paper's own loop, and
CrossQ's settings on SAC.
"""

from __future__ import annotations

from rl_jax.training.recipes import Recipe, Recipes, Setting

PENDULUM = "rl_jax/Pendulum-v1"
HUMANOID = "rl_jax/Humanoid-v5"
ANT = "rl_jax/Ant-v5"
MUJOCO = tuple(
    f"rl_jax/{name}-v5"
    for name in (
        "InvertedPendulum",
        "InvertedDoublePendulum",
        "HalfCheetah",
        "Hopper",
        "Walker2d",
        "Ant",
        "Reacher",
        "Swimmer",
        "Humanoid",
    )
)

# Pendulum: small networks, 4 envs with 4 updates per iteration (one update per env step),
# learning after 1,000 random steps, evaluation every 1,000 env steps per seed.
PENDULUM_CONFIG: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 250,
    "learning_starts": 1_000,
    "actor_hidden": (64, 64),
    "critic_hidden": (64, 64),
}
PENDULUM_HPARAMS: dict[str, Setting] = {"actor_lr": 1e-3, "critic_lr": 1e-3, "alpha_lr": 1e-3}

# The CPU loop of TD3's half-cheetah recipe: 4 envs per seed with 4 updates per iteration (one
# update per env step, 4x fewer crossings into the MuJoCo C step), batch 128 (half the FLOPs of
# the paper's 256), 10,000 random steps, evaluation every 5,000 env steps.
CPU_LOOP: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 4,
    "iterations_per_chunk": 1_250,
    "batch_size": 128,
    "learning_starts": 10_000,
}
# The MuJoCo CPU recipe: that loop with TD3's CPU networks, 128 x 128 at rate 1e-3 for actor,
# critics and temperature (about a third of the paper's 256 x 256's FLOPs per update), chosen
# over the paper's networks and rates in the same loop by return against wall-clock on half
# cheetah; the actor and temperature step every second critic step (as TD3's actor), chosen over
# every step on half cheetah, hopper, walker and ant by return against wall-clock.
MUJOCO_CONFIG: dict[str, Setting] = {
    **CPU_LOOP,
    "actor_hidden": (128, 128),
    "critic_hidden": (128, 128),
    "policy_delay": 2,
}
MUJOCO_HPARAMS: dict[str, Setting] = {"actor_lr": 1e-3, "critic_lr": 1e-3, "alpha_lr": 1e-3}
# Ant: the same with Adam's b1 at 0.5 for actor and critics (the temperature's Adam keeps 0.9), as
# the SAC runs of CrossQ's code set it; chosen over 0.9 on ant by return, and not taken on half
# cheetah, hopper and walker, where it did not raise the return.
ANT_CONFIG: dict[str, Setting] = {**MUJOCO_CONFIG, "adam_b1": 0.5}
# Humanoid's raw contact forces (up to ~1,900 beside joint angles of ~1) saturate an actor that
# reads them raw (as TD3's did): standardised here too.
HUMANOID_CONFIG: dict[str, Setting] = {**MUJOCO_CONFIG, "normalize_obs": True}

# The paper's settings (Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications",
# Table 1): 256 x 256 ReLU networks, Adam at 3e-4 for actor, critics and temperature, batch 256,
# one gradient step per env step in one env, a 10^6 replay, tau 0.005, gamma 0.99, target
# entropy -|A|. The 10,000 uniformly random steps first are the authors' code's (softlearning's
# development variants: 10 episodes of 1,000 steps); evaluation every 5,000 steps.
SAC_PAPER_CONFIG: dict[str, Setting] = {
    "num_envs": 1,
    "updates_per_iteration": 1,
    "iterations_per_chunk": 5_000,
    "batch_size": 256,
    "buffer_size": 1_000_000,
    "learning_starts": 10_000,
    "actor_hidden": (256, 256),
    "critic_hidden": (256, 256),
}
SAC_PAPER_HPARAMS: dict[str, Setting] = {
    "actor_lr": 3e-4,
    "critic_lr": 3e-4,
    "alpha_lr": 3e-4,
    "tau": 0.005,
    "gamma": 0.99,
    "target_entropy_per_dim": -1.0,
}

# CrossQ (Bhatt et al. 2024, "CrossQ: Batch Normalization in Deep Reinforcement Learning for
# Greater Sample Efficiency and Simplicity") on SAC, as its code (adityab/CrossQ, train.py's
# "crossq" settings) runs it: batch renormalisation (momentum 0.99, plain batch norm for the
# first 100,000 updates) in the critics and in the actor (its default "brn_actor" mode), no
# target networks ((s, a) and (s', a') in one forward pass), 2,048 x 2,048 critics, a 256 x 256
# actor, Adam with b1 0.5 for actor and critics at rate 1e-3 (the temperature's Adam too, with
# its default b1), actor and temperature updated every 3rd critic update, one update per env
# step in one env, batch 256, 5,000 random steps first.
CROSSQ_OPTIONS: dict[str, Setting] = {
    "critic_norm": "batch_renorm",
    "actor_norm": "batch_renorm",
    "renorm_warmup": 100_000,
    "target_networks": False,
    "adam_b1": 0.5,
    "policy_delay": 3,
    "actor_hidden": (256, 256),
}
CROSSQ_CONFIG: dict[str, Setting] = {
    **SAC_PAPER_CONFIG,
    **CROSSQ_OPTIONS,
    "learning_starts": 5_000,
    "critic_hidden": (2048, 2048),
}
CROSSQ_HPARAMS: dict[str, Setting] = {"actor_lr": 1e-3, "critic_lr": 1e-3, "alpha_lr": 1e-3}
# The same in the CPU loop (4 envs x 4 updates per iteration) at a CPU size: 256-wide critics,
# CrossQ's batch of 256 kept (batch statistics of 128 would be noisier than CrossQ's).
CROSSQ_CPU_CONFIG: dict[str, Setting] = {
    **CROSSQ_CONFIG,
    **CPU_LOOP,
    "batch_size": 256,
    "learning_starts": 5_000,
    "critic_hidden": (256, 256),
}

RECIPES = Recipes(
    Recipe(
        "default",
        "64x64 networks at rate 1e-3, 4 envs x 4 updates per iteration, 1,000 warm-up steps",
        PENDULUM_CONFIG,
        PENDULUM_HPARAMS,
        envs=(PENDULUM,),
    ),
    Recipe(
        "default",
        "CPU: 128x128 at rate 1e-3 in TD3's CPU loop (batch 128, 4 envs x 4 updates, 10,000 "
        "warm-up steps), actor and temperature every 2nd update",
        MUJOCO_CONFIG,
        MUJOCO_HPARAMS,
        envs=tuple(env_id for env_id in MUJOCO if env_id not in (HUMANOID, ANT)),
    ),
    Recipe(
        "default",
        "the MuJoCo CPU recipe with Adam b1 0.5 for actor and critics",
        ANT_CONFIG,
        MUJOCO_HPARAMS,
        envs=(ANT,),
    ),
    Recipe(
        "default",
        "the MuJoCo CPU recipe, observations standardised by running statistics",
        HUMANOID_CONFIG,
        MUJOCO_HPARAMS,
        envs=(HUMANOID,),
    ),
    Recipe(
        "sac-paper",
        "the SAC paper's: 256x256 at rate 3e-4, one env, one update per step, batch 256, "
        "10,000 warm-up steps",
        SAC_PAPER_CONFIG,
        SAC_PAPER_HPARAMS,
    ),
    Recipe(
        "crossq",
        "CrossQ (Bhatt et al. 2024): batch renorm, no targets, 2048x2048 critics, Adam b1 0.5, "
        "rate 1e-3, policy delay 3, one env, batch 256",
        CROSSQ_CONFIG,
        CROSSQ_HPARAMS,
    ),
    Recipe(
        "crossq-cpu",
        "CrossQ with 256x256 critics in the CPU loop (4 envs x 4 updates, batch 256)",
        CROSSQ_CPU_CONFIG,
        CROSSQ_HPARAMS,
    ),
)
