"""REINFORCE's recipes (``rl_jax.training.recipes``): each env's default on top of the ``Config``
and ``Hyperparams`` defaults (gymnasium's REINFORCE tutorial), each with the reason it was chosen.
The runs that chose them: RESULTS.md#reinforces-recipes-how-they-were-chosen.
"""

from __future__ import annotations

from rl_jax.training.recipes import Recipe, Recipes, Setting

_CONFIGS: dict[str, dict[str, Setting]] = {
    # The tutorial's network, with 16 episodes per update and normalised returns (and a 10x
    # larger rate, below)
    "rl_jax/InvertedPendulum-v5": {"num_envs": 16, "normalize_returns": True},
    "rl_jax/InvertedDoublePendulum-v5": {
        "num_envs": 32,
        "hidden": (64, 64),
        "baseline": "value",
        "value_hidden": (64, 64),
        "normalize_returns": True,
        "normalize_obs": True,
        # A small state-free exploration std: with a larger one the noisy training episodes end
        # early, and the gradient only ever sees short episodes.
        "std_mode": "param",
        "initial_std": 0.2,
        "squash_mean": True,  # an unbounded mean could leave the action bounds and stay there
    },
    "rl_jax/CartPole-v1": {"num_envs": 16, "normalize_returns": True},  # untuned
}
_HPARAMS: dict[str, dict[str, float]] = {
    # A fast rate that reaches 1,000 early, falling to 0 over the script's 300 updates so that
    # the policy stops collapsing and recovering.
    "rl_jax/InvertedPendulum-v5": {"learning_rate": 3e-3, "lr_decay_updates": 300.0},
    "rl_jax/InvertedDoublePendulum-v5": {
        "learning_rate": 1.5e-3,  # faster than 1e-3, steadier than 3e-3
        "max_grad_norm": 0.5,
        "lr_decay_updates": 300.0,  # = the script's default budget: the final policy settles
    },
    "rl_jax/CartPole-v1": {"learning_rate": 1e-3},
}

_ABOUT = {
    "rl_jax/InvertedPendulum-v5": "gymnasium's tutorial network, 16 envs, rate 3e-3 to 0",
    "rl_jax/InvertedDoublePendulum-v5": "64x64, value baseline, 32 envs, rate 1.5e-3 to 0",
    "rl_jax/CartPole-v1": "the tutorial's network, 16 envs, rate 1e-3 (untuned)",
}
RECIPES = Recipes(
    *(
        Recipe("default", about, _CONFIGS[env_id], _HPARAMS.get(env_id, {}), envs=(env_id,))
        for env_id, about in _ABOUT.items()
    )
)
