"""PPO's recipes: whole, named settings per env (``rl_jax.training.recipes``), over the defaults
of ``ppo_config``. Envs without a recipe of their own train on those defaults. How they were
chosen: docs/learners/ppo.md#how-the-recipes-were-chosen.
"""

from __future__ import annotations

from rl_jax.training.recipes import Recipe, Recipes, Setting

MUJOCO = tuple(
    f"rl_jax/{name}-v5"
    for name in (
        "InvertedPendulum",
        "InvertedDoublePendulum",
        "HalfCheetah",
        "Hopper",
        "Walker2d",
        "Swimmer",
        "Reacher",
        "Ant",
        "Humanoid",
    )
)

# CleanRL's ppo_continuous_action.py (its Args and make_env), setting by setting: the reference
# the MuJoCo rows compare with.
CLEANRL_CONFIG: dict[str, Setting] = {
    "num_envs": 1,
    "num_steps": 2048,
    "num_epochs": 10,
    "num_minibatches": 32,
    "iterations_per_chunk": 5,  # evaluated every 10,240 env steps
    "hidden": (64, 64),
    "activation": "tanh",
    "initial_std": 1.0,
    "normalize_obs": True,
    "normalize_rewards": True,
    "normalize_advantages": True,
    "clip_value_loss": True,
}
CLEANRL_HPARAMS: dict[str, Setting] = {
    "learning_rate": 3e-4,
    "lr_decay_steps": 1_000_000.0,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "clip_eps": 0.2,
    "value_clip_eps": 0.2,
    "vf_coef": 0.5,
    "ent_coef": 0.0,
    "max_grad_norm": 0.5,
    "adam_eps": 1e-5,
    "reward_clip": 10.0,
}

# Vectorised: CleanRL's 2,048-step batch from 64 envs x 32 steps, chosen on half cheetah by
# return against wall-clock (RESULTS.md#ppos-vectorised-recipe).
MUJOCO_CONFIG: dict[str, Setting] = {
    **CLEANRL_CONFIG,
    "num_envs": 64,
    "num_steps": 32,
    "iterations_per_chunk": 10,  # 10 evaluation episodes cost about 10,240 steps of training
}

# CartPole: rl-baselines3-zoo's tuned settings, chosen over three others by 30-seed runs
# (RESULTS.md#sac-and-ppo-first-measurements-and-ppo-on-cartpole).
CARTPOLE_CONFIG: dict[str, Setting] = {
    "num_envs": 16,
    "num_steps": 32,
    "num_epochs": 10,
    "num_minibatches": 2,
    "iterations_per_chunk": 10,  # evaluated every 5,120 env steps
    "clip_value_loss": False,
}
CARTPOLE_HPARAMS: dict[str, Setting] = {
    "learning_rate": 1e-3,
    "lr_decay_steps": 100_000.0,
    "gamma": 0.98,
    "gae_lambda": 0.8,
    "ent_coef": 0.0,
}

# Frames: DQN's conv torso at DQN's pixel budget, otherwise untuned (RESULTS.md#ppo-from-pixels).
PIXELS_CONFIG: dict[str, Setting] = {
    "normalize_rewards": True,  # unscaled, the value loss's gradient fills the clipped norm
    "num_envs": 8,
    "num_steps": 128,
    "num_epochs": 4,
    "num_minibatches": 4,
    "iterations_per_chunk": 5,
}
PIXELS_HPARAMS: dict[str, Setting] = {"learning_rate": 2.5e-4, "lr_decay_steps": 200_000.0}

RECIPES = Recipes(
    Recipe(
        "default",
        "16 envs x 32 steps, 10 epochs x 2 minibatches, rate 1e-3 to 0 over 100k steps",
        CARTPOLE_CONFIG,
        CARTPOLE_HPARAMS,
        envs=("rl_jax/CartPole-v1",),
        total_steps=100_000,
    ),
    Recipe(
        "default",
        "conv torso shared by actor and critic, 8 envs x 128 steps (untuned)",
        PIXELS_CONFIG,
        PIXELS_HPARAMS,
        envs=("rl_jax/CartPolePixels-v1",),
        total_steps=200_000,
    ),
    Recipe(
        "default",
        "64 envs x 32 steps, 10 epochs x 32 minibatches, CleanRL's rates and norms",
        MUJOCO_CONFIG,
        CLEANRL_HPARAMS,
        envs=MUJOCO,
        total_steps=1_000_000,
    ),
    Recipe(
        "cleanrl",
        "CleanRL's ppo_continuous_action.py: 1 env x 2048 steps, 10 epochs x 32 minibatches",
        CLEANRL_CONFIG,
        CLEANRL_HPARAMS,
        envs=MUJOCO,
        total_steps=1_000_000,
    ),
)
