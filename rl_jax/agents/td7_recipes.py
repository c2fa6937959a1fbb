"""TD7's recipes (``rl_jax.training.recipes``): its published settings, which are the ``Config``
and ``Hyperparams`` defaults, and the same learner at CPU sizes."""

from __future__ import annotations

from rl_jax.training.recipes import Recipe, Recipes

TD7_RECIPES = Recipes(
    Recipe(
        "default",
        "TD7's published settings: 256x256 networks, 256-d embeddings, LAP, hard target copies "
        "every 250 updates, value clipping, policy checkpoints on the TD3 paper's loop, rate 3e-4",
    ),
    # TD7's own sizes are too slow for a CPU (docs/learners/td7.md#how-the-recipes-were-chosen).
    Recipe(
        "cpu",
        "TD7 at CPU sizes: 128x128 networks, 128-d embeddings, the half-cheetah CPU loop (4 envs "
        "x 4 updates, batch 128, 10,000 warm-up steps), rate 3e-4",
        {
            "num_envs": 4,
            "updates_per_iteration": 4,
            "iterations_per_chunk": 1250,
            "batch_size": 128,
            "learning_starts": 10_000,
            "actor_hidden": (128, 128),
            "critic_hidden": (128, 128),
            "embedding_dim": 128,
            "embedding_hidden": (128, 128),
        },
        throughput=(61.0, 5),  # measured: docs/learners/td7.md#how-the-recipes-were-chosen
    ),
)
