"""The baseline our users ran before rl_jax: a single-file PyTorch TD3 on gymnasium's C MuJoCo.

One env, a numpy replay buffer, one gradient update per env step, the TD3 paper's
hyperparameters (the same as ``rl_jax.agents.td3``'s paper recipe). Written in the style of the
single-file scripts people learn from, so that the comparison in BENCHMARKS.md is against what a
user would really run on this machine: two such processes at a time, one thread each.

    python -m bench.torch_td3 --seed 1 --total-steps 300000 --out bench/results/torch_td3_s1.jsonl

Every ``--eval-every`` env steps it writes one JSON line: step, wall-clock seconds spent
training (evaluation time excluded, which favours the baseline), updates/s and env steps/s so far,
and the mean return of ``--eval-episodes`` deterministic episodes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from torch import nn


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--env-id", default="HalfCheetah-v5", help="gymnasium id")
    p.add_argument("--seed", type=int, default=1, help="seed for torch, numpy and the env")
    p.add_argument("--total-steps", type=int, default=1_000_000, help="env steps")
    p.add_argument("--learning-starts", type=int, default=25_000, help="uniform random steps")
    p.add_argument("--buffer-size", type=int, default=1_000_000, help="replay capacity")
    p.add_argument("--batch-size", type=int, default=256, help="minibatch size")
    p.add_argument("--hidden", type=int, default=256, help="width of both hidden layers")
    p.add_argument("--lr", type=float, default=3e-4, help="Adam learning rate (both nets)")
    p.add_argument("--gamma", type=float, default=0.99, help="discount")
    p.add_argument("--tau", type=float, default=0.005, help="Polyak averaging of targets")
    p.add_argument("--exploration-noise", type=float, default=0.1, help="action-scale stddev")
    p.add_argument("--policy-noise", type=float, default=0.2, help="target smoothing stddev")
    p.add_argument("--noise-clip", type=float, default=0.5, help="target smoothing clip")
    p.add_argument("--policy-delay", type=int, default=2, help="critic updates per actor update")
    p.add_argument("--eval-every", type=int, default=10_000, help="env steps between evals")
    p.add_argument("--eval-episodes", type=int, default=5, help="episodes per evaluation")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    p.add_argument("--stop-at-return", type=float, default=None, help="stop once eval >= this")
    p.add_argument("--out", type=Path, default=None, help="JSON-lines log (default: stdout)")
    p.add_argument(
        "--time-only", type=int, default=0, metavar="N",
        help="benchmark mode: time --learning-starts random steps, then N steps with an update\n"
        "each, print one JSON line of rates and exit (no evaluation, no log file)",
    )  # fmt: skip
    return p.parse_args(argv)


def mlp(n_in: int, n_out: int, hidden: int = 256) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
        nn.Linear(hidden, n_out),
    )  # fmt: skip


class Actor(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, low: np.ndarray, high: np.ndarray, hidden: int):
        super().__init__()
        self.net = mlp(obs_dim, act_dim, hidden)
        self.register_buffer("scale", torch.tensor((high - low) / 2.0, dtype=torch.float32))
        self.register_buffer("bias", torch.tensor((high + low) / 2.0, dtype=torch.float32))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.net(obs)) * self.scale + self.bias


class Critic(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, hidden: int):
        super().__init__()
        self.net = mlp(obs_dim + act_dim, 1, hidden)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs, action], dim=-1)).squeeze(-1)


class Replay:
    """Preallocated numpy ring buffer; ``terminated`` (not ``done``) masks the bootstrap."""

    def __init__(self, capacity: int, obs_dim: int, act_dim: int):
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.action = np.zeros((capacity, act_dim), np.float32)
        self.reward = np.zeros(capacity, np.float32)
        self.terminated = np.zeros(capacity, np.float32)
        self.capacity, self.size, self.cursor = capacity, 0, 0

    def add(self, obs, action, reward, next_obs, terminated) -> None:
        i = self.cursor
        self.obs[i], self.action[i], self.reward[i] = obs, action, reward
        self.next_obs[i], self.terminated[i] = next_obs, terminated
        self.cursor = (i + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def sample(self, rng: np.random.Generator, batch: int) -> list[torch.Tensor]:
        idx = rng.integers(0, self.size, batch)
        arrays = (self.obs, self.action, self.reward, self.next_obs, self.terminated)
        return [torch.from_numpy(a[idx]) for a in arrays]


def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    with torch.no_grad():
        for t, s in zip(target.parameters(), source.parameters(), strict=True):
            t.mul_(1.0 - tau).add_(s, alpha=tau)


def evaluate(actor: Actor, env_id: str, episodes: int, seed: int) -> float:
    env = gym.make(env_id)
    returns = []
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        done, total = False, 0.0
        while not done:
            with torch.no_grad():
                action = actor(torch.as_tensor(obs, dtype=torch.float32)).numpy()
            obs, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return float(np.mean(returns))


class TD3:
    def __init__(self, args: argparse.Namespace, env: gym.Env):
        obs_dim = env.observation_space.shape[0]
        act_dim = env.action_space.shape[0]
        low, high = env.action_space.low, env.action_space.high
        self.args, self.low, self.high = args, low, high
        self.scale = torch.tensor((high - low) / 2.0, dtype=torch.float32)
        self.actor = Actor(obs_dim, act_dim, low, high, args.hidden)
        self.actor_target = Actor(obs_dim, act_dim, low, high, args.hidden)
        self.actor_target.load_state_dict(self.actor.state_dict())
        self.critics = nn.ModuleList([Critic(obs_dim, act_dim, args.hidden) for _ in range(2)])
        self.critics_target = nn.ModuleList(
            [Critic(obs_dim, act_dim, args.hidden) for _ in range(2)]
        )
        self.critics_target.load_state_dict(self.critics.state_dict())
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=args.lr)
        self.critic_opt = torch.optim.Adam(self.critics.parameters(), lr=args.lr)

    def update(self, batch: list[torch.Tensor], update_index: int) -> None:
        obs, action, reward, next_obs, terminated = batch
        a = self.args
        with torch.no_grad():
            noise = (torch.randn_like(action) * a.policy_noise * self.scale).clamp(
                -a.noise_clip * self.scale, a.noise_clip * self.scale
            )
            next_action = self.actor_target(next_obs) + noise
            next_action = torch.max(torch.min(next_action, self.actor.bias + self.scale),
                                    self.actor.bias - self.scale)  # fmt: skip
            q_next = torch.min(*(c(next_obs, next_action) for c in self.critics_target))
            target = reward + a.gamma * (1.0 - terminated) * q_next
        critic_loss = sum(((c(obs, action) - target) ** 2).mean() for c in self.critics)
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()
        if update_index % a.policy_delay == 0:
            actor_loss = -self.critics[0](obs, self.actor(obs)).mean()
            self.actor_opt.zero_grad()
            actor_loss.backward()
            self.actor_opt.step()
            soft_update(self.actor_target, self.actor, a.tau)
            soft_update(self.critics_target, self.critics, a.tau)

    def act(self, obs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        with torch.no_grad():
            action = self.actor(torch.as_tensor(obs, dtype=torch.float32)).numpy()
        action = action + rng.normal(0.0, self.args.exploration_noise, action.shape) * (
            self.scale.numpy()
        )
        return np.clip(action, self.low, self.high).astype(np.float32)


def seeded_setup(args: argparse.Namespace) -> tuple[np.random.Generator, gym.Env, TD3]:
    """Threads, seeds, the env and the agent, as every entry point starts."""
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    env = gym.make(args.env_id)
    env.action_space.seed(args.seed)
    return rng, env, TD3(args, env)


def time_only(args: argparse.Namespace) -> dict[str, float]:
    """Env steps/s of the random warm-up and of the learning phase (one env step plus one update
    per step), measured separately: what a projection of a full run multiplies out."""
    rng, env, agent = seeded_setup(args)
    total = args.learning_starts + args.time_only
    replay = Replay(total, *env.observation_space.shape, *env.action_space.shape)
    obs, _ = env.reset(seed=args.seed)
    marks = [time.perf_counter()]
    for step in range(1, total + 1):
        learning = step > args.learning_starts
        action = agent.act(obs, rng) if learning else env.action_space.sample()
        next_obs, reward, terminated, truncated, _ = env.step(action)
        replay.add(obs, action, reward, next_obs, float(terminated))
        obs = next_obs if not (terminated or truncated) else env.reset()[0]
        if learning:
            agent.update(replay.sample(rng, args.batch_size), step - args.learning_starts - 1)
        if step == args.learning_starts:
            marks.append(time.perf_counter())
    marks.append(time.perf_counter())
    random_s, learning_s = marks[1] - marks[0], marks[-1] - marks[1]
    return {
        "random_steps_per_s": round(args.learning_starts / random_s, 1),
        "learning_steps_per_s": round(args.time_only / learning_s, 1),
        "updates_per_s": round(args.time_only / learning_s, 1),
        "threads": args.threads,
    }


def train(args: argparse.Namespace) -> None:
    rng, env, agent = seeded_setup(args)
    replay = Replay(min(args.buffer_size, args.total_steps), *env.observation_space.shape,
                    *env.action_space.shape)  # fmt: skip
    out = open(args.out, "a") if args.out else None  # noqa: SIM115 - closed below
    obs, _ = env.reset(seed=args.seed)
    train_seconds, updates, start = 0.0, 0, time.perf_counter()
    for step in range(1, args.total_steps + 1):
        if step <= args.learning_starts:
            action = env.action_space.sample()
        else:
            action = agent.act(obs, rng)
        next_obs, reward, terminated, truncated, _ = env.step(action)
        replay.add(obs, action, reward, next_obs, float(terminated))
        obs = next_obs if not (terminated or truncated) else env.reset()[0]
        if step > args.learning_starts:
            agent.update(replay.sample(rng, args.batch_size), updates)
            updates += 1
        if step % args.eval_every == 0:
            train_seconds += time.perf_counter() - start
            eval_return = evaluate(agent.actor, args.env_id, args.eval_episodes, 10_000 + step)
            row = {
                "step": step, "seed": args.seed, "eval_return": eval_return,
                "train_seconds": round(train_seconds, 2), "updates": updates,
                "env_steps_per_s": round(step / train_seconds, 1),
                "threads": args.threads,
            }  # fmt: skip
            print(json.dumps(row), file=out or None, flush=True)
            if args.stop_at_return is not None and eval_return >= args.stop_at_return:
                break
            start = time.perf_counter()
    if out:
        out.close()


if __name__ == "__main__":
    arguments = parse_args()
    if arguments.time_only:
        print(json.dumps(time_only(arguments)), flush=True)
    else:
        train(arguments)
