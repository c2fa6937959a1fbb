"""Stable-Baselines3's PPO timed on gymnasium's HalfCheetah-v5: the peer ``bench_ppo_sb3`` sets
beside our PPO. Runs in the peers' venv (``bench/peers.py``); imports nothing of rl_jax.

    .venv-peers/bin/python bench/sb3_ppo.py --steps 1000000 --threads 2

The settings of our ``cleanrl`` PPO recipe (CleanRL's ``ppo_continuous_action``), in SB3's
terms: one env, rollouts of 2,048 steps, 10 epochs of minibatches of 64 (32 per epoch), 64 x 64
tanh actor and critic apart (``net_arch=dict(pi=[64, 64], vf=[64, 64])``), orthogonal init, a
state-independent log-std from 0, Adam at 3e-4 (eps 1e-5, SB3's for PPO) falling linearly to 0,
gamma 0.99, lambda 0.95, the ratio and the value clipped at 0.2, advantages standardised per
minibatch, no entropy bonus, gradients clipped to norm 0.5; observations standardised and rewards
scaled by the std of discounted returns, both clipped to +-10 (``VecNormalize``), actions
clipped to the env's bounds (SB3 does it itself). Our loss is ``policy + 0.5 * 0.5 * mean squared
value error``; SB3's has no 0.5 inside, so its ``vf_coef`` is 0.25.

Start-up (building the env and the model) is timed apart; then ``model.learn(--steps)`` is
timed, which collects ceil(steps / 2,048) rollouts and trains after each. PyTorch runs on
``--threads`` threads (``torch.set_num_threads``); the env steps in the main thread. Prints one
JSON line: env steps, seconds, env steps/s, start-up seconds, threads, versions and the load.
"""

from __future__ import annotations

import argparse
import json
import os
import time

ROLLOUT = 2048  # env steps per rollout (n_steps x one env)
VF_COEF = 0.25  # ours: 0.5 x 0.5 mean squared error; SB3: vf_coef x mean squared error


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: env, env steps to time, torch threads, seed."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env-id", default="HalfCheetah-v5", help="gymnasium id")
    parser.add_argument("--steps", type=int, default=20_480, help="env steps to time (learn())")
    parser.add_argument("--threads", type=int, default=os.cpu_count(), help="torch threads")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    if args.steps < 1 or args.threads < 1:
        parser.error("--steps and --threads must be >= 1")
    return args


def build(env_id: str, seed: int):
    """The model of the module docstring, on a fresh normalised env."""
    import gymnasium as gym
    import torch  # type: ignore[import-not-found]  # the peers' venv's, as the two below
    from stable_baselines3 import PPO  # type: ignore[import-not-found]
    from stable_baselines3.common.vec_env import (  # type: ignore[import-not-found]
        DummyVecEnv,
        VecNormalize,
    )

    env = DummyVecEnv([lambda: gym.make(env_id)])
    env = VecNormalize(env, norm_obs=True, norm_reward=True, clip_obs=10.0, clip_reward=10.0)
    return PPO(
        "MlpPolicy",
        env,
        learning_rate=lambda remaining: 3e-4 * remaining,
        n_steps=ROLLOUT,
        batch_size=64,
        n_epochs=10,
        gamma=0.99,
        gae_lambda=0.95,
        clip_range=0.2,
        clip_range_vf=0.2,
        normalize_advantage=True,
        ent_coef=0.0,
        vf_coef=VF_COEF,
        max_grad_norm=0.5,
        policy_kwargs={
            "net_arch": {"pi": [64, 64], "vf": [64, 64]},
            "activation_fn": torch.nn.Tanh,
            "log_std_init": 0.0,
            "ortho_init": True,
        },
        seed=seed,
        device="cpu",
        verbose=0,
    )


def main(argv: list[str] | None = None) -> None:
    """Build, time ``learn``, print the JSON line."""
    args = parse_args(argv)
    import gymnasium
    import mujoco
    import stable_baselines3
    import torch

    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    model = build(args.env_id, args.seed)
    startup = time.perf_counter() - start
    start = time.perf_counter()
    model.learn(total_timesteps=args.steps)
    seconds = time.perf_counter() - start
    result = {
        "peer": "sb3",
        "env_id": args.env_id,
        "env_steps": int(model.num_timesteps),
        "seconds": round(seconds, 3),
        "env_steps_per_s": round(model.num_timesteps / seconds, 1),
        "startup_s": round(startup, 3),
        "threads": torch.get_num_threads(),
        "stable_baselines3": stable_baselines3.__version__,
        "torch": torch.__version__,
        "gymnasium": gymnasium.__version__,
        "mujoco": mujoco.__version__,
        "load": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
