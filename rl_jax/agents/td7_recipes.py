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
    # A SALE update is ~6x the arithmetic of TD3's at the same sizes, too slow at TD7's own sizes
    # on the paper's loop for a CPU: the half-cheetah CPU loop (4 envs x 4 updates per iteration,
    # batch 128, 10,000 random steps) at 128 sizes instead.
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
        throughput=(61.0, 5),
    ),
)
