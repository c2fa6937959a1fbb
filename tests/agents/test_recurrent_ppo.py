"""Recurrent PPO (``rl_jax.agents.recurrent_ppo``): the state restarts exactly at episode starts,
training sequences replay what acting computed from their stored initial states, the gradient of
the scanned loss equals that of a step-by-step Python unroll, and a memory probe that no
feed-forward policy can solve is solved by it and not by PPO."""

from __future__ import annotations

import dataclasses
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax
import rl_jax.envs.core.probes  # noqa: F401  (registers the probes)
from rl_jax.agents import ppo_parts
from rl_jax.agents import recurrent_ppo as rppo
from rl_jax.agents.policy_gradient import entropy, log_prob
from rl_jax.agents.ppo import ppo
from rl_jax.run import learners
from rl_jax.training.algorithm import hooks

PROBE = "rl_jax/ProbeRememberFirstDiscrete-v0"  # first obs +-1, then 0; the 3rd step pays


def probe_config(cell: str = "lstm", **overrides) -> rppo.Config:
    settings = dict(
        cell=cell,
        num_envs=16,
        num_steps=12,
        seq_len=6,
        num_epochs=4,
        num_minibatches=2,
        cell_size=16,
        iterations_per_chunk=5,
        num_eval_envs=64,
    )
    return rppo.recurrent_ppo.default_config(PROBE, **{**settings, **overrides})


def flat(carry) -> jax.Array:
    """An LSTM's (c, h) or a GRU's h as one array [..., features]."""
    return jnp.concatenate(jax.tree.leaves(carry), axis=-1)


@functools.cache
def collector(config: rppo.Config):
    """``rppo.collect`` for ``config``, compiled once for every test that collects with it."""
    return jax.jit(lambda state, key: rppo.collect(state, key, config))


@pytest.mark.parametrize("cell", ["lstm", "gru"])
def test_the_state_restarts_exactly_at_episode_starts(cell):
    config = probe_config(cell, seq_len=4)
    hparams = rppo.recurrent_ppo.default_hyperparams(PROBE)
    state = rppo.init(jax.random.key(0), config, hparams)
    _, rollout = collector(config)(state, jax.random.key(1))
    # the probe's episodes are 3 steps long: starts at steps 0, 3, 6, 9 of every env
    expected = np.tile((np.arange(config.num_steps) % 3 == 0)[:, None], (1, config.num_envs))
    np.testing.assert_array_equal(rollout.start, expected)
    carry = flat(rollout.carry)
    np.testing.assert_array_equal(carry[expected], 0.0)
    assert np.all(np.abs(np.asarray(carry[~expected])).max(axis=-1) > 0)
    # elsewhere the state is the cell's output of the step before: nothing else touches it
    previous = jax.tree.map(lambda x: x[:-1], rollout.carry)
    stepped = jax.vmap(lambda c, o: rppo.apply(state.agent.params, c, o, config)[0])(
        previous, rollout.obs[:-1]
    )
    np.testing.assert_allclose(
        flat(stepped)[~expected[1:]], carry[1:][~expected[1:]], rtol=1e-5, atol=1e-6
    )


def test_sequences_replay_what_acting_computed_from_their_stored_states():
    """seq_len 4 over 3-step episodes: starts fall inside sequences, and the unroll resets."""
    config = probe_config("lstm", seq_len=4)
    hparams = rppo.recurrent_ppo.default_hyperparams(PROBE)
    state = rppo.init(jax.random.key(0), config, hparams)
    _, rollout = collector(config)(state, jax.random.key(1))
    fields = (rollout.obs, rollout.start, rollout.v_tm1, rollout.log_mu, rollout.action)
    obs, start, v_tm1, log_mu, action = rppo.to_sequences(fields, config)
    initial = jax.tree.map(lambda x: x[:, 0], rppo.to_sequences(rollout.carry, config))
    time_first = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731
    policy = rppo.unroll(state.agent.params, initial, time_first(obs), time_first(start), config)
    np.testing.assert_allclose(policy["value"], time_first(v_tm1), rtol=1e-5, atol=1e-6)
    replayed = log_prob(policy, time_first(action))
    np.testing.assert_allclose(replayed, time_first(log_mu), rtol=1e-5, atol=1e-6)
    # and the sequences are each env's steps in order
    np.testing.assert_array_equal(obs[1], np.asarray(rollout.obs)[4:8, 0])


def reference_loss(params, batch, carry, hparams, config):
    """``rppo.loss_fn`` written as a Python loop over the steps of every sequence."""
    zero = rppo.initial_carry(config)
    outputs = []
    for t in range(batch.obs.shape[1]):
        start = batch.start[:, t]
        carry = jax.tree.map(
            lambda c, z, start=start: jnp.where(start[:, None], z[None], c), carry, zero
        )
        carry, out = rppo.make_network(config).apply(params, carry, batch.obs[:, t])
        outputs.append(out)
    policy = {k: jnp.stack([o[k] for o in outputs], axis=1) for k in outputs[0]}
    log_pi = log_prob(policy, batch.action)
    advantage = ppo_parts.normalize_advantages(batch.advantage)
    policy_loss = ppo_parts.clipped_surrogate_loss(
        log_pi, batch.log_mu, advantage, hparams.clip_eps
    )
    value_loss = ppo_parts.value_loss(policy["value"], batch.target)
    mean_entropy = jnp.mean(entropy(policy))
    return policy_loss + hparams.vf_coef * value_loss - hparams.ent_coef * mean_entropy


@pytest.mark.parametrize(
    ("cell", "critic_cell", "head_hidden"), [("lstm", False, ()), ("gru", True, (4,))]
)
def test_the_gradient_through_a_sequence_matches_a_step_by_step_unroll(
    cell, critic_cell, head_hidden
):
    """The GRU case also gives the value a cell of its own and both heads a layer."""
    config = probe_config(cell, cell_size=8, critic_cell=critic_cell, head_hidden=head_hidden)
    hparams = rppo.recurrent_ppo.default_hyperparams(PROBE, ent_coef=0.05)
    state = rppo.init(jax.random.key(0), config, hparams)
    keys = jax.random.split(jax.random.key(2), 8)
    batch_size, length = 3, 7
    batch = rppo.Sequences(
        obs=jax.random.normal(keys[0], (batch_size, length, 1)),
        start=jnp.zeros((batch_size, length), bool).at[:, 0].set(True).at[1, 4].set(True),
        action=jax.random.randint(keys[1], (batch_size, length), 0, 2),
        log_mu=jnp.log(jax.random.uniform(keys[2], (batch_size, length), minval=0.3, maxval=0.7)),
        advantage=jax.random.normal(keys[3], (batch_size, length)),
        target=jax.random.normal(keys[4], (batch_size, length)),
    )
    carry = jax.tree.map(
        lambda z: jax.random.normal(keys[5], (batch_size, *z.shape)), rppo.initial_carry(config)
    )
    batch = batch._replace(start=batch.start.at[0, 0].set(False))  # one stored state kept
    params = state.agent.params
    # each gradient as one jitted program: run op by op, the step-by-step unroll dispatches
    # thousands of small operations
    scanned = jax.jit(jax.grad(lambda p: rppo.loss_fn(p, batch, carry, hparams, config)[0]))(params)
    looped = jax.jit(jax.grad(lambda p: reference_loss(p, batch, carry, hparams, config)))(params)
    for a, b in zip(jax.tree.leaves(scanned), jax.tree.leaves(looped), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
    assert max(float(jnp.max(jnp.abs(g))) for g in jax.tree.leaves(scanned)) > 0


def trained(algorithm, config, hparams, chunks: int) -> tuple:
    """``(state, eval return)`` after ``chunks`` chunks from seed 0."""
    state = algorithm.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(lambda s: algorithm.train_chunk(s, config, hparams))
    for _ in range(chunks):
        state, metrics = chunk(state)
    return state, float(metrics.eval_return)


def train(algorithm, config, hparams, chunks: int) -> float:
    return trained(algorithm, config, hparams, chunks)[1]


@functools.cache
def remembering_run(cell: str, normalize_obs: bool) -> tuple:
    """``(state, config, eval return)`` of the memory probe after 4 chunks: one compiled program
    for the test that it remembers and the test that its policy acts (the GRU's)."""
    hparams = rppo.recurrent_ppo.default_hyperparams(PROBE, learning_rate=3e-3, ent_coef=0.01)
    config = probe_config(cell, normalize_obs=normalize_obs)
    return config, *trained(rppo.recurrent_ppo, config, hparams, 4)


@pytest.mark.parametrize(("cell", "normalize_obs"), [("lstm", False), ("gru", True)])
def test_recurrent_ppo_remembers_the_first_observation(cell, normalize_obs):
    """3,840 env steps: every evaluation episode paid 1."""
    assert remembering_run(cell, normalize_obs)[2] >= 0.95


def test_feed_forward_ppo_cannot():
    """The same budget: PPO sees 0 on the step that pays, so it can only guess (mean ~0)."""
    settings = dict(num_envs=16, num_steps=12, num_epochs=4, num_minibatches=2, hidden=(16,))
    config = ppo.default_config(PROBE, iterations_per_chunk=5, num_eval_envs=64, **settings)
    hparams = ppo.default_hyperparams(PROBE, learning_rate=3e-3)
    assert train(ppo, config, hparams, 4) < 0.5


def test_it_is_registered_with_a_recipe_and_a_recurrent_policy():
    assert learners.ALGORITHMS["recurrent_ppo"] == "rl_jax.agents.recurrent_ppo:recurrent_ppo"
    assert rl_jax.recurrent_ppo is rppo.recurrent_ppo
    config = rppo.recurrent_ppo.default_config("rl_jax/CartPoleNoVel-v1")
    assert (config.num_envs, config.num_steps, config.num_epochs) == (8, 32, 20)
    assert config.normalize_obs and config.cell == "lstm"
    carry = hooks(rppo.recurrent_ppo).initial_policy_state(config)
    assert [x.shape for x in jax.tree.leaves(carry)] == [(64,), (64,)]
    with pytest.raises(ValueError, match="seq_len"):
        dataclasses.replace(config, seq_len=5)


def test_its_policy_acts_from_one_observation_and_a_state():
    """The GRU run of ``test_recurrent_ppo_remembers_the_first_observation`` (its policy also
    standardises the observations)."""
    config, state, _ = remembering_run("gru", True)
    step = jax.jit(rppo.recurrent_ppo.policy(state, config))
    for first in (-1.0, 1.0):
        carry = rppo.recurrent_ppo.initial_policy_state(config)
        for obs in (first, 0.0, 0.0):
            action, carry = step(carry, jnp.array([obs], jnp.float32))
        assert int(action) == (1 if first > 0 else 0)  # index 1 stands for +1


# ---- the probes: known values (every episode is one step: the state is always the zero one) ----
PROBE_GAMMA = 0.5


@functools.cache
def probe_run(env_id: str):
    settings = dict(num_envs=8, num_steps=16, seq_len=8, num_epochs=4, num_minibatches=2)
    config = rppo.recurrent_ppo.default_config(
        env_id, **settings, iterations_per_chunk=60, cell_size=32, hidden=(32,), num_eval_envs=4
    )
    hparams = rppo.recurrent_ppo.default_hyperparams(
        gamma=PROBE_GAMMA, learning_rate=3e-3, ent_coef=0.0
    )
    state = rppo.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(lambda s: rppo.train_chunk(s, config, hparams))
    for _ in range(2):
        state, metrics = chunk(state)
    return state, config, metrics


def outputs_at(state, config, values: list[float]) -> dict:
    carry = rppo.initial_carry(config)
    carry = jax.tree.map(lambda z: jnp.broadcast_to(z, (len(values), *z.shape)), carry)
    obs = jnp.asarray(values, jnp.float32)[:, None]
    return rppo.apply(state.agent.params, carry, obs, config)[1]


def test_critic_learns_the_values_of_the_termination_probe():
    state, config, _ = probe_run("rl_jax/ProbeTermination-v0")
    got = np.asarray(outputs_at(state, config, [0.0, 1.0])["value"])
    np.testing.assert_allclose(got, [0.0, 1.0], atol=0.05)


def test_a_truncation_bootstraps_from_the_final_observation_with_the_state_reached():
    """As sb3-contrib's RecurrentPPO does: the value of the true final observation, read with
    the state the cell reached on the step that the time limit cut (the episode would have gone
    on with it), while the next step starts from the zero state."""
    config = rppo.recurrent_ppo.default_config(
        "rl_jax/ProbeTruncation-v0", num_envs=16, num_steps=4, seq_len=4, cell_size=8
    )
    state = rppo.init(jax.random.key(0), config, rppo.recurrent_ppo.default_hyperparams())
    _, rollout = collector(config)(state, jax.random.key(1))
    assert np.all(np.asarray(rollout.truncated)) and not np.any(np.asarray(rollout.terminated))
    assert np.all(np.asarray(rollout.start)) and np.all(np.asarray(flat(rollout.carry)) == 0)
    params = state.agent.params
    for t in range(config.num_steps):
        reached, _ = rppo.apply(
            params, jax.tree.map(lambda x, t=t: x[t], rollout.carry), rollout.obs[t], config
        )
        final_obs = 1.0 - rollout.obs[t]  # the probe flips its observation, then the limit cuts
        _, expected = rppo.apply(params, reached, final_obs, config)
        np.testing.assert_allclose(rollout.v_t[t], expected["value"], rtol=1e-5, atol=1e-6)
    zero = jax.tree.map(lambda x: x[0], rollout.carry)
    _, from_zero = rppo.apply(params, zero, 1.0 - rollout.obs[0], config)
    assert not np.allclose(rollout.v_t[0], from_zero["value"])


def test_policy_finds_the_best_action_of_the_action_reward_probe():
    state, config, metrics = probe_run("rl_jax/ProbeActionReward-v0")
    assert float(outputs_at(state, config, [0.0])["mean"][0, 0]) == pytest.approx(0.5, abs=0.1)
    assert float(metrics.eval_return) == pytest.approx(1.0, abs=0.01)


def test_a_resumed_run_equals_one_that_never_stopped_and_its_policy_remembers(tmp_path):
    """The cell's state of every env is in the checkpoint: two seeds, 2 chunks straight vs 1
    chunk then a resume; the loaded policy then answers the probe from its memory."""
    config = {"num_envs": 16, "num_steps": 12, "seq_len": 6, "num_minibatches": 2}
    config |= {"cell_size": 16, "iterations_per_chunk": 5, "num_eval_envs": 64}
    hparams = {"learning_rate": 3e-3, "ent_coef": 0.01}
    chunk = 16 * 12 * 5
    common = dict(seeds=2, config=config, hparams=hparams, quiet=True)
    straight = rl_jax.train(
        "recurrent_ppo", PROBE, total_steps=2 * chunk, out=tmp_path / "a", **common
    )
    rl_jax.train("recurrent_ppo", PROBE, total_steps=chunk, out=tmp_path / "b", **common)
    resumed = rl_jax.resume(tmp_path / "b", total_steps=2 * chunk, quiet=True)

    def rows(run):
        lines = (run.run_dir / "metrics.jsonl").read_text().splitlines()
        return [json.loads(line) for line in lines]

    keep = ("step", "seed", "eval_return", "train_return", "policy_loss")
    assert [{k: r.get(k) for k in keep} for r in rows(resumed)] == [
        {k: r.get(k) for k in keep} for r in rows(straight)
    ]
    policy = rl_jax.load_policy(tmp_path / "a")
    for first in (-1.0, 1.0):
        policy.reset()
        actions = [int(policy(np.array([obs], np.float32))) for obs in (first, 0.0, 0.0)]
        assert actions[-1] == (1 if first > 0 else 0)


def test_normalize_rewards_folds_each_envs_running_discounted_return_into_the_stats():
    """With ``normalize_rewards`` an iteration folds every step's running discounted return
    (restarted where an episode ended, carried across rollouts) into the return statistics, as
    PPO's option does: checked against the rollout's rewards recomputed in numpy."""
    config = rppo.recurrent_ppo.default_config(
        "rl_jax/CartPoleNoVel-v1", num_envs=4, num_steps=16, seq_len=8, normalize_rewards=True
    )
    hparams = rppo.recurrent_ppo.default_hyperparams("rl_jax/CartPoleNoVel-v1")
    state = rppo.init(jax.random.key(0), config, hparams)
    iteration = jax.jit(rppo.train_iteration, static_argnums=1)
    running = np.zeros(config.num_envs)
    returns = []
    for _ in range(2):  # the second rollout starts from the first's carried returns
        _, collect_key, _ = jax.random.split(state.key, 3)
        _, rollout = collector(config)(state, collect_key)
        ended = np.asarray(rollout.terminated | rollout.truncated)
        for r, done in zip(np.asarray(rollout.r_t), ended, strict=True):
            running = hparams.gamma * running + r
            returns.append(running.copy())
            running = np.where(done, 0.0, running)
        state, _ = iteration(state, config, hparams)
        np.testing.assert_allclose(state.discounted_return, running, rtol=1e-5)
    assert ended.any()  # episodes ended inside the rollouts: the restart was exercised
    g = np.concatenate(returns)
    assert float(state.return_stats.count) == pytest.approx(g.size, abs=1e-3)
    np.testing.assert_allclose(state.return_stats.mean, [g.mean()], rtol=1e-4)
    np.testing.assert_allclose(state.return_stats.var, [g.var()], rtol=1e-3)
    assert (
        rppo.init(
            jax.random.key(0), dataclasses.replace(config, normalize_rewards=False), hparams
        ).return_stats
        is None
    )
