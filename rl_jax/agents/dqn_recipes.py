"""DQN's recipes (``rl_jax.training.recipes``): each env's default on top of the ``Config`` and
``Hyperparams`` defaults (CleanRL's classic-control DQN), each with the reason it was chosen and
a link to the runs that chose it.
"""

from __future__ import annotations

from rl_jax.training.recipes import Recipe, Recipes, Setting

# The classic-control base: wider layers, a faster rate and a short epsilon decay (as in
# rl-baselines3-zoo's tuned DQN), with 4 envs and one update per 2 env steps.
_CLASSIC: dict[str, Setting] = {
    "num_envs": 4,
    "updates_per_iteration": 2,
    "iterations_per_chunk": 1000,
    "learning_starts": 1000,
    "buffer_size": 100_000,
    "batch_size": 64,
    "hidden": (256, 256),
    "target_update_period": 100,
}
# CartPole: the policy a run ends with is TD7's checkpoint, since the greedy policy alone keeps
# collapsing and recovering after it first scores 500 (RESULTS.md#dqn-on-cartpole).
_CARTPOLE: dict[str, Setting] = {
    **_CLASSIC,
    "hidden": (64, 64),  # enough here, at a fraction of 256x256's cost
    "n_step": 3,
    "policy_checkpoints": True,
    "checkpoint_episodes": 20,  # TD7's; fewer let checkpoints short of 500 through
    "checkpoint_episodes_from": 20_000,
}
_CONFIGS: dict[str, dict[str, Setting]] = {
    "rl_jax/CartPole-v1": _CARTPOLE,
    # Pixels: the settings that got the conv torso learning (RESULTS.md#dqn-from-pixels).
    "rl_jax/CartPolePixels-v1": {
        **_CLASSIC,
        "hidden": (256,),
        "buffer_size": 50_000,  # frame pairs: about 0.7 GB per seed
        "batch_size": 32,
        "updates_per_iteration": 1,  # one update per 4 env steps
        "double": True,
        "n_step": 3,
        "target_update_period": 500,
        "crop_drawn_rows": True,  # the other rows are always white: the same net, cheaper
        "norm": "layer",  # learns faster than without
    },
    "rl_jax/InvertedPendulum-v5": _CLASSIC,
    "rl_jax/Rocket-v0": {**_CLASSIC, "action_bins": 3},
    # The settle variant: finer thrust and LayerNorm bring every seed to rest
    # (RESULTS.md#the-rocket).
    "rl_jax/RocketSettle-v0": {**_CLASSIC, "action_bins": 5, "norm": "layer"},
}
_FAST_DECAY = {"learning_rate": 1e-3, "epsilon_decay_steps": 8000.0, "epsilon_end": 0.04}
_HPARAMS: dict[str, dict[str, float]] = {
    # A constant rate (the checkpoint keeps what was learned); epsilon 0.01 after 8k steps, so
    # that the training episodes that assess a copy are nearly its greedy policy's.
    "rl_jax/CartPole-v1": {**_FAST_DECAY, "learning_rate": 3e-3, "epsilon_end": 0.01},
    # The rate falls to 0 over the script's 200k steps, so that the policy the run ends with is a
    # settled one: at a constant rate it kept collapsing and recovering.
    "rl_jax/CartPolePixels-v1": {**_FAST_DECAY, "learning_rate": 5e-4, "lr_decay_steps": 200_000.0},
    "rl_jax/InvertedPendulum-v5": _FAST_DECAY,
    "rl_jax/Rocket-v0": {"learning_rate": 1e-3, "epsilon_decay_steps": 50_000.0},
    # gamma 0.995 as TD3's rocket recipe: at 0.99 creeping in scores about as well as arriving.
    "rl_jax/RocketSettle-v0": {
        "learning_rate": 1e-3,
        "epsilon_decay_steps": 50_000.0,
        "gamma": 0.995,
    },
}

_ABOUT = {
    "rl_jax/CartPole-v1": "64x64, 3-step returns, rate 3e-3, TD7's policy checkpoints",
    "rl_jax/CartPolePixels-v1": "conv torso, Double DQN, 3-step returns, LayerNorm, rate to 0",
    "rl_jax/InvertedPendulum-v5": "the classic-control base: 256x256, 4 envs, rate 1e-3",
    "rl_jax/Rocket-v0": "the classic-control base, thrust {-1, 0, +1}",
    "rl_jax/RocketSettle-v0": "thrust {-1, -0.5, 0, 0.5, 1}, LayerNorm, gamma 0.995",
}
# (env steps/s per seed, seeds) for run plans' estimates, measured as
# docs/learners/dqn.md#how-the-recipes-were-chosen says
_THROUGHPUT = {"rl_jax/CartPolePixels-v1": (117.0, 3)}
RECIPES = Recipes(
    *(
        Recipe(
            "default",
            about,
            _CONFIGS[env_id],
            _HPARAMS.get(env_id, {}),
            envs=(env_id,),
            throughput=_THROUGHPUT.get(env_id),
        )
        for env_id, about in _ABOUT.items()
    )
)
