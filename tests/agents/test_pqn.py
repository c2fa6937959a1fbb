"""PQN: its Q(lambda) targets against a plain loop (exact values), the probe envs' known values,
legal-action masks in acting and in the bootstrap, a command-line run that resumes bit for bit,
a MinAtar chunk, and (slow) CartPole at the recipe's budget."""

import dataclasses
import functools
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from run_helpers import leaves_bytes

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import pqn
from rl_jax.envs.core.probes import Truncation
from rl_jax.errors import guard
from rl_jax.run import cli, command
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.plan import make_plan
from rl_jax.run.run_dir import CHECKPOINT_DIR


# ---- Q(lambda) targets ------------------------------------------------------------------------
def reference_targets(reward, terminated, truncated, v, gamma, lam):
    """The Q(lambda) returns of one rollout ``[T, N]``, one env and one step at a time, from the
    episode's ends: a step that ended an episode (or the rollout) bootstraps from its own
    ``v`` (not after a termination); any other mixes ``v`` with the next step's return."""
    f32 = np.float32
    steps, count = reward.shape
    out = np.zeros((steps, count), f32)
    for n in range(count):
        following = None
        for t in reversed(range(steps)):
            discount = f32(0.0) if terminated[t, n] else f32(gamma)
            if following is None or terminated[t, n] or truncated[t, n]:
                value = v[t, n]
            else:
                value = (f32(1.0) - f32(lam)) * v[t, n] + f32(lam) * following
            out[t, n] = reward[t, n] + discount * value
            following = out[t, n]
    return out


def random_rollout(seed, steps=9, count=5):
    rng = np.random.default_rng(seed)
    terminated = rng.random((steps, count)) < 0.2
    truncated = ~terminated & (rng.random((steps, count)) < 0.15)
    reward = rng.normal(size=(steps, count)).astype(np.float32)
    v = rng.normal(size=(steps, count)).astype(np.float32)
    return reward, terminated, truncated, v


def targets_of(reward, terminated, truncated, v, gamma, lam):
    zeros = jnp.zeros(reward.shape)
    rollout = pqn.Rollout(
        obs=zeros,
        action=zeros,
        r_t=jnp.asarray(reward),
        v_t=jnp.asarray(v),
        terminated=jnp.asarray(terminated),
        truncated=jnp.asarray(truncated),
        episode_return=zeros,
    )
    hparams = pqn.default_hyperparams(gamma=gamma, q_lambda=lam)
    return np.asarray(jax.jit(pqn.rollout_targets)(rollout, hparams))


@pytest.mark.parametrize("lam", [0.0, 0.7, 1.0])
def test_q_lambda_targets_equal_the_loop_with_terminations_and_truncations(lam):
    for seed in range(3):
        data = random_rollout(seed)
        gamma = np.float32(0.9)
        expected = reference_targets(*data, gamma, lam)
        np.testing.assert_array_equal(targets_of(*data, gamma, lam), expected)


def test_lambda_zero_is_one_step_and_lambda_one_the_return_to_the_episode_or_rollout_end():
    reward, terminated, truncated, v = random_rollout(7)
    gamma = np.float32(0.9)
    discount = np.where(terminated, np.float32(0.0), gamma)
    np.testing.assert_array_equal(
        targets_of(reward, terminated, truncated, v, gamma, 0.0), reward + discount * v
    )
    # lambda 1: discounted rewards to the first end, then v there (0 after a termination).
    monte_carlo = np.zeros_like(reward)
    steps, count = reward.shape
    for n in range(count):
        for t in range(steps):
            total, scale = 0.0, 1.0
            for k in range(t, steps):
                total += scale * reward[k, n]
                scale *= 0.0 if terminated[k, n] else float(gamma)
                if terminated[k, n] or truncated[k, n] or k == steps - 1:
                    total += scale * v[k, n]
                    break
            monte_carlo[t, n] = total
    np.testing.assert_allclose(
        targets_of(reward, terminated, truncated, v, gamma, 1.0), monte_carlo, rtol=1e-5, atol=1e-5
    )


def test_rewards_are_scaled_before_the_targets():
    reward, terminated, truncated, v = random_rollout(3)
    zeros = jnp.zeros(reward.shape)
    rollout = pqn.Rollout(zeros, zeros, jnp.asarray(reward), zeros, jnp.asarray(terminated),
                          jnp.asarray(truncated), zeros)  # fmt: skip
    plain = pqn.rollout_targets(rollout, pqn.default_hyperparams(q_lambda=0.5))
    scaled = pqn.rollout_targets(rollout, pqn.default_hyperparams(q_lambda=0.5, reward_scale=0.1))
    np.testing.assert_allclose(scaled, 0.1 * np.asarray(plain), rtol=1e-5, atol=1e-7)


# ---- probes -----------------------------------------------------------------------------------
GAMMA = 0.5
TOL = 0.05
PROBE_CONFIG = {
    "num_envs": 8,
    "num_steps": 16,
    "num_epochs": 2,
    "num_minibatches": 2,
    "iterations_per_chunk": 100,
    "hidden": (32, 32),
    "num_eval_envs": 4,
}
# Uniformly random actions throughout: Q-learning is off-policy, and every action gets data.
PROBE_HPARAMS = {
    "gamma": GAMMA,
    "q_lambda": 0.8,
    "learning_rate": 1e-3,
    "epsilon_start": 1.0,
    "epsilon_end": 1.0,
}


@functools.cache
def train_probe(env_id: str, chunks: int = 4):
    config = pqn.default_config(env_id, **PROBE_CONFIG)
    hparams = pqn.default_hyperparams(env_id, **PROBE_HPARAMS)
    state = pqn.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(pqn.train_chunk, static_argnums=1)
    for _ in range(chunks):
        state, metrics = chunk(state, config, hparams)
    return config, state, metrics


def q_at(config, state, positions):
    obs = jnp.asarray(positions, jnp.float32)[:, None]
    return np.asarray(pqn.q_values(state.agent.params, obs, config))


def test_pqn_learns_the_two_step_chain_through_the_lambda_mixture():
    config, state, metrics = train_probe("rl_jax/ProbeTwoStepDiscrete-v0")
    q = q_at(config, state, [0.0, 1.0])
    np.testing.assert_allclose(q[0], GAMMA, atol=TOL)  # bootstraps from Q(1) = 1
    np.testing.assert_allclose(q[1], 1.0, atol=TOL)
    assert int(metrics.updates) == 4 * 100 * 2 * 2


@pytest.mark.parametrize("terminal", [False, True], ids=["truncation", "termination"])
def test_pqn_bootstraps_through_truncation_only(terminal):
    kind = "Termination" if terminal else "Truncation"
    config, state, _ = train_probe(f"rl_jax/Probe{kind}Discrete-v0")
    q = q_at(config, state, [0.0, 1.0])
    for position in (0, 1):
        expected = Truncation.true_q(float(position), GAMMA, terminal)
        np.testing.assert_allclose(q[position], expected, atol=TOL)


# ---- legal-action masks -----------------------------------------------------------------------
MASK_ENV = "rl_jax/ProbeFatalIllegalActions-v0"
HIGH = 100.0


def biased_state(config):
    """A fresh state whose Q-values are ``[HIGH, 0, 0, 0]`` in every state: action 0, illegal
    in about half of them, is the best of all."""
    hparams = pqn.default_hyperparams()
    state = pqn.init(jax.random.key(1), config, hparams)
    params = jax.tree.map(lambda x: x, state.agent.params)
    head = sorted(name for name in params["params"] if name.startswith("Dense"))[-1]
    layer = params["params"][head]
    bias = jnp.zeros_like(layer["bias"]).at[0].set(HIGH)
    params["params"][head] = {"kernel": jnp.zeros_like(layer["kernel"]), "bias": bias}
    return dataclasses.replace(state, agent=dataclasses.replace(state.agent, params=params))


@pytest.mark.parametrize("epsilon", [0.0, 1.0], ids=["greedy", "random"])
def test_acting_and_the_bootstrap_take_legal_actions_only(epsilon):
    config = pqn.default_config(MASK_ENV, num_envs=16, num_steps=40, hidden=(8,))
    state = biased_state(config)
    assert state.action_mask is not None and state.action_mask.shape == (16, 4)
    _, _, _, rollout = jax.jit(pqn.collect, static_argnums=5)(
        state.agent,
        state.env_state,
        state.obs,
        jax.random.key(2),
        jnp.float32(epsilon),
        config,
        state.action_mask,
    )
    # An illegal action terminates: there is none, greedy (action 0 is the best) or random.
    assert not np.any(rollout.terminated)
    legal = np.asarray(rollout.obs) > 0.5  # the observation is the mask
    assert np.all(np.take_along_axis(legal, np.asarray(rollout.action)[..., None], axis=-1))
    if epsilon == 0.0:  # greedy: action 0 wherever legal
        np.testing.assert_array_equal(np.asarray(rollout.action) == 0, legal[..., 0])
    # The bootstrap's max is HIGH only where action 0 is legal in the next observation.
    v = np.asarray(rollout.v_t)
    ended = np.asarray(rollout.truncated)
    np.testing.assert_array_equal(v[:-1][~ended[:-1]], (HIGH * legal[1:, :, 0])[~ended[:-1]])
    assert set(np.unique(v)) <= {0.0, HIGH}
    # The greedy policy, as evaluation runs it, takes the best legal action.
    policy = pqn.pqn.policy(state, config)
    masks = jnp.array([[False, True, True, False], [True, False, False, True]])
    np.testing.assert_array_equal(policy(masks.astype(jnp.float32), masks), [1, 0])


# ---- the command line, resumed ----------------------------------------------------------------
ENV_ID = "rl_jax/CartPole-v1"
FLAGS = [
    "--num-envs", "4", "--num-steps", "8", "--num-epochs", "2", "--num-minibatches", "2",
    "--iterations-per-chunk", "2", "--num-eval-envs", "2", "--hidden", "16,16",
    "--seeds", "2", "--log-interval", "0", "--checkpoint-interval", "0",
]  # fmt: skip
CHUNK = 4 * 8 * 2


def train_cli(argv) -> int:
    return guard(lambda: cli.run_experiment(argv=["--algo", "pqn", "--env", ENV_ID, *argv]))


def final_state(run_dir: Path):
    spec = command.spec_for(pqn.pqn, ENV_ID, FLAGS)
    plan = make_plan(dataclasses.replace(spec, out=run_dir))
    with Checkpointer(run_dir / CHECKPOINT_DIR, read_only=True) as checkpointer:
        state, meta = checkpointer.restore(plan.template)
    return state, meta["step"]


def test_a_command_line_run_trains_and_resumes_bit_for_bit(tmp_path):
    whole, split = tmp_path / "whole", tmp_path / "split"
    assert train_cli([*FLAGS, "--total-steps", str(4 * CHUNK), "--out", str(whole)]) == 0
    assert train_cli([*FLAGS, "--total-steps", str(2 * CHUNK), "--out", str(split)]) == 0
    stopped, stopped_step = final_state(split)
    assert train_cli(["--resume", str(split), "--total-steps", str(4 * CHUNK)]) == 0
    for name in ("config.json", "metrics.jsonl"):
        assert (whole / name).exists()
    assert len((whole / "metrics.jsonl").read_text().splitlines()) == 2 * 4  # seeds x chunks
    full, full_step = final_state(whole)
    resumed, resumed_step = final_state(split)
    assert stopped_step == 2 * CHUNK and full_step == resumed_step == 4 * CHUNK
    assert leaves_bytes(resumed) == leaves_bytes(full)
    assert int(resumed.clock.updates) > int(stopped.clock.updates) > 0
    assert leaves_bytes(resumed.agent.params) != leaves_bytes(stopped.agent.params)
    assert metric_rows(whole) == metric_rows(split)


def metric_rows(run_dir: Path) -> list[dict[str, float]]:
    """Every row of a run's ``metrics.jsonl``, its timings left out."""
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").open()]
    return [{k: v for k, v in row.items() if "time" not in k} for row in rows]


# ---- MinAtar -----------------------------------------------------------------------------------
@pytest.mark.slow  # ~6 s of compiling; MinAtar itself is stepped in tests/envs/test_gymnax.py
def test_one_minatar_chunk_compiles_and_runs():
    config = pqn.default_config(
        "rl_jax/Breakout-MinAtar",
        num_envs=4,
        num_steps=4,
        num_minibatches=2,
        num_epochs=1,
        iterations_per_chunk=1,
        num_eval_envs=1,
        hidden=(16,),
        conv_layers=(4, 3, 1),
    )
    assert isinstance(config, pqn.ImageConfig)
    hparams = pqn.default_hyperparams("rl_jax/Breakout-MinAtar")
    state = pqn.init(jax.random.key(0), config, hparams)
    assert state.obs.shape == (4, 10, 10, 4)
    state, metrics = jax.jit(pqn.train_chunk, static_argnums=1)(state, config, hparams)
    assert int(metrics.env_steps) == 16 and int(metrics.updates) == 2
    for leaf in jax.tree.leaves(state.agent.params):
        assert np.all(np.isfinite(leaf))
    assert np.isfinite(float(metrics.extra["loss"]))


def test_recipes_name_the_paper_settings():
    cartpole = pqn.default_config(ENV_ID)
    assert (cartpole.num_envs, cartpole.num_steps, cartpole.hidden) == (32, 64, (256, 256))
    assert float(pqn.default_hyperparams(ENV_ID).reward_scale) == pytest.approx(0.1)
    minatar = pqn.default_config("rl_jax/Asterix-MinAtar")
    assert isinstance(minatar, pqn.ImageConfig) and minatar.batch_size == 128 * 32
    assert float(pqn.default_hyperparams("rl_jax/Asterix-MinAtar").q_lambda) == pytest.approx(0.65)
    assert isinstance(pqn.default_config("rl_jax/CartPolePixels-v1"), pqn.PixelConfig)
    with pytest.raises(TypeError, match="discrete actions"):
        pqn.init(
            jax.random.key(0), pqn.default_config("rl_jax/Pendulum-v1"), pqn.default_hyperparams()
        )


# ---- slow: CartPole at the recipe's budget ----------------------------------------------------
@pytest.mark.slow
def test_pqn_solves_cartpole_in_most_seeds(tmp_path):
    from rl_jax.run.runner import run
    from rl_jax.run.spec import RunSpec

    spec = RunSpec(
        algorithm=pqn.pqn,
        env_id=ENV_ID,
        config=pqn.default_config(ENV_ID),
        hparams=(pqn.default_hyperparams(ENV_ID),),
        out=tmp_path / "run",
        seeds=4,
        total_steps=500_000,
        checkpoint_interval=0.0,
        log_interval=1e9,
    )
    assert run(spec, notify=lambda message: None).step >= 500_000
    rows = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").open()]
    best = {seed: max(r["eval_return"] for r in rows if r["seed"] == seed) for seed in range(4)}
    assert sum(value >= 500.0 for value in best.values()) >= 3, best
