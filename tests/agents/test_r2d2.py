"""R2D2: each part against a reference written here step by step in numpy (value rescaling,
n-step double-Q targets over a sequence with episode ends, burn-in, resets, priorities, the
sequence replay), then the learner on the loop: a few chunks, its recurrent policy through
``load_policy``, and (slow) CartPoleNoVel-v1 over ten seeds."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax
from rl_jax.agents import r2d2, r2d2_parts
from rl_jax.run import learners
from rl_jax.training.algorithm import hooks
from rl_jax.training.prioritized import PrioritizedBuffer
from rl_jax.training.replay import Transition

ENV_ID = "rl_jax/CartPoleNoVel-v1"


# ---- value rescaling ---------------------------------------------------------------------------
def h_reference(x: float, eps: float) -> float:
    return float(np.sign(x) * (np.sqrt(abs(x) + 1.0) - 1.0) + eps * x)


def h_inverse_reference(y: float, eps: float) -> float:
    """Solves h(x) = y by bisection (h is strictly increasing), in float64."""
    low, high = -1e9, 1e9
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if h_reference(middle, eps) < y else (low, middle)
    return 0.5 * (low + high)


@pytest.mark.parametrize("eps", [1e-3, 1e-2])
def test_value_rescaling_and_its_inverse_match_the_reference(eps):
    xs = np.array([-3000.0, -57.5, -1.0, -0.01, 0.0, 0.3, 1.0, 8.0, 99.0, 500.0, 4321.0])
    got = np.asarray(jax.jit(r2d2_parts.value_rescale)(jnp.asarray(xs, jnp.float32), eps))
    np.testing.assert_allclose(got, [h_reference(x, eps) for x in xs], rtol=1e-5, atol=1e-6)
    ys = np.array([-60.0, -3.2, -0.5, 0.0, 1e-5, 0.01, 1.0, 7.5, 40.0, 120.0])
    inverse = np.asarray(r2d2_parts.inverse_value_rescale(jnp.asarray(ys, jnp.float32), eps))
    expected = [h_inverse_reference(y, eps) for y in ys]
    np.testing.assert_allclose(inverse, expected, rtol=2e-4, atol=1e-4)
    # the identity both ways
    back = r2d2_parts.inverse_value_rescale(r2d2_parts.value_rescale(jnp.asarray(xs), eps), eps)
    np.testing.assert_allclose(np.asarray(back), xs, rtol=2e-4, atol=1e-3)
    there = r2d2_parts.value_rescale(r2d2_parts.inverse_value_rescale(jnp.asarray(ys), eps), eps)
    np.testing.assert_allclose(np.asarray(there), ys, rtol=1e-5, atol=1e-7)


# ---- n-step double-Q targets over a sequence ---------------------------------------------------
def n_step_reference(reward, terminated, truncated, v, gamma, n):
    """Returns ``[T]`` of one sequence, one step at a time."""
    steps = len(reward)
    out = np.zeros(steps)
    for t in range(steps):
        total, scale = 0.0, 1.0
        for k in range(t, min(t + n, steps)):
            total += scale * reward[k]
            if terminated[k]:
                break
            scale *= gamma
            if truncated[k] or k == min(t + n, steps) - 1:
                total += scale * v[k]
                break
        out[t] = total
    return out


def test_n_step_targets_of_a_hand_worked_sequence_with_a_terminal_in_the_middle():
    reward = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0], np.float32)
    terminated = np.array([0, 0, 1, 0, 0, 0], bool)
    truncated = np.zeros(6, bool)
    v = np.array([10.0, 20.0, 30.0, 40.0, 50.0, 60.0], np.float32)  # of each step's next obs
    gamma = 0.5
    # by hand: the episode ends at step 2 (no bootstrap); from step 3 on the window of 3 stops
    # at the sequence's last step, which bootstraps from v[5]
    by_hand = [1 + 0.5 * 2 + 0.25 * 3, 2 + 0.5 * 3, 3, 4 + 2.5 + 1.5 + 0.125 * 60, 5 + 3 + 15, 36]
    np.testing.assert_allclose(
        n_step_reference(reward, terminated, truncated, v, gamma, 3), by_hand
    )
    discount = gamma * (1.0 - terminated.astype(np.float32))
    got = r2d2_parts.n_step_targets(
        jnp.asarray(reward)[:, None],
        jnp.asarray(discount)[:, None],
        jnp.asarray(v)[:, None],
        jnp.asarray(terminated)[:, None],
        3,
    )
    np.testing.assert_allclose(np.asarray(got)[:, 0], by_hand, rtol=1e-6)


@pytest.mark.parametrize("n", [1, 2, 5])
def test_rescaled_targets_match_the_reference_with_terminations_and_truncations(n):
    rng = np.random.default_rng(n)
    steps, batch, gamma, eps = 9, 4, 0.9, 1e-3
    reward = rng.normal(size=(steps, batch)).astype(np.float32)
    terminated = rng.uniform(size=(steps, batch)) < 0.15
    truncated = ~terminated & (rng.uniform(size=(steps, batch)) < 0.15)
    q_target = rng.normal(size=(steps, batch)).astype(np.float32)  # rescaled units
    discount = gamma * (1.0 - terminated.astype(np.float32))
    got = r2d2_parts.rescaled_n_step_targets(
        jnp.asarray(reward),
        jnp.asarray(discount),
        jnp.asarray(q_target),
        jnp.asarray(terminated | truncated),
        n,
        eps,
    )
    for b in range(batch):
        v = [h_inverse_reference(float(x), eps) for x in q_target[:, b]]
        returns = n_step_reference(reward[:, b], terminated[:, b], truncated[:, b], v, gamma, n)
        expected = [h_reference(g, eps) for g in returns]
        np.testing.assert_allclose(np.asarray(got)[:, b], expected, rtol=1e-4, atol=1e-5)


def test_sequence_priorities_mix_the_max_and_the_mean():
    td = np.array([[0.5, -2.0], [-1.5, 0.0], [1.0, 1.0]], np.float32)  # [T, B]
    got = np.asarray(r2d2_parts.sequence_priorities(jnp.asarray(td), 0.9))
    expected = [0.9 * max(abs(td[:, b])) + 0.1 * np.mean(abs(td[:, b])) for b in range(2)]
    np.testing.assert_allclose(got, expected, rtol=1e-6)


# ---- the network: resets and burn-in -----------------------------------------------------------
def small_config(**overrides) -> r2d2.Config:
    settings = dict(hidden=(8,), cell_size=6, seq_len=7, burn_in=3, seq_period=3, n_step=2)
    settings |= dict(num_envs=2, batch_size=4, learning_starts=14, iterations_per_chunk=20)
    return r2d2.r2d2.default_config(ENV_ID, **(settings | overrides))


def network_and_sequences(seed=0):
    config = small_config()
    rng = np.random.default_rng(seed)
    steps, batch = config.seq_len, config.batch_size
    obs = jnp.asarray(rng.normal(size=(batch, steps, 4)), jnp.float32)
    ended = rng.uniform(size=(batch, steps)) < 0.3
    terminated = jnp.asarray(ended & (rng.uniform(size=(batch, steps)) < 0.5))
    truncated = jnp.asarray(ended) & ~terminated
    step = Transition(
        obs=obs,
        action=jnp.asarray(rng.integers(0, 2, (batch, steps)), jnp.int32),
        reward=jnp.asarray(rng.normal(size=(batch, steps)), jnp.float32),
        next_obs=jnp.asarray(rng.normal(size=(batch, steps, 4)), jnp.float32),
        terminated=terminated,
        truncated=truncated,
    )
    state = tuple(
        jnp.asarray(rng.normal(size=(batch, config.cell_size)), jnp.float32) for _ in "ch"
    )
    params = r2d2.make_network(config).init(jax.random.key(seed), state, obs[:, 0])
    return config, params, r2d2_parts.Sequence(step, state)


def step_by_step(params, config, state, obs, starts):
    """The carries after each step and the q of each, one step at a time: ``obs [B, T, ...]``."""
    carries, qs = [], []
    for t in range(obs.shape[1]):
        zero = r2d2.initial_carry(config)
        state = tuple(
            jnp.where(starts[:, t, None], z[None], s) for s, z in zip(state, zero, strict=True)
        )
        state, q = r2d2.apply(params, state, obs[:, t], config)
        carries.append(state)
        qs.append(q)
    return carries, jnp.stack(qs, axis=1)


def test_the_state_after_burn_in_equals_a_step_by_step_unroll_with_its_resets():
    config, params, batch = network_and_sequences()
    time_first = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), batch.steps)
    starts = r2d2_parts.episode_starts(time_first.terminated, time_first.truncated)
    assert np.any(np.asarray(starts[: config.burn_in]))  # a reset inside the burn-in
    burnt = r2d2.advance(
        params,
        batch.start_state,
        time_first.obs[: config.burn_in],
        starts[: config.burn_in],
        config,
    )
    carries, _ = step_by_step(
        params, config, batch.start_state, batch.steps.obs[:, : config.burn_in], starts.T
    )
    for got, expected in zip(burnt, carries[-1], strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(expected), rtol=1e-5, atol=1e-6)


def test_the_state_resets_exactly_at_episode_starts_inside_a_sequence():
    config, params, batch = network_and_sequences(1)
    time_first = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), batch.steps)
    starts = r2d2_parts.episode_starts(time_first.terminated, time_first.truncated)
    q, q_next = r2d2.unroll(params, batch.start_state, time_first, starts, config)
    carries, expected = step_by_step(params, config, batch.start_state, batch.steps.obs, starts.T)
    np.testing.assert_allclose(np.swapaxes(np.asarray(q), 0, 1), expected, rtol=1e-5, atol=1e-6)
    for t in range(config.seq_len):  # the next obs is read with the state reached on the step
        _, want = r2d2.apply(params, carries[t], batch.steps.next_obs[:, t], config)
        np.testing.assert_allclose(np.asarray(q_next[t]), want, rtol=1e-5, atol=1e-6)
    # at a start, the q is the zero state's whatever came before
    zero = jax.tree.map(
        lambda z: jnp.broadcast_to(z, (config.batch_size, *z.shape)), r2d2.initial_carry(config)
    )
    for b, t in zip(*np.nonzero(np.asarray(starts.T)), strict=True):
        _, fresh = r2d2.apply(params, zero, batch.steps.obs[:, t], config)
        np.testing.assert_allclose(expected[b, t], fresh[b], rtol=1e-5, atol=1e-6)
    assert np.any(np.asarray(starts)) and not np.any(np.asarray(starts[0]))


def test_burn_in_steps_and_the_stored_state_get_no_gradient():
    config, params, batch = network_and_sequences(2)
    hparams = r2d2.r2d2.default_hyperparams(ENV_ID)
    weights = jnp.ones(config.batch_size, jnp.float32)

    def loss_of(obs, state):
        sequences = batch._replace(steps=batch.steps._replace(obs=obs), start_state=state)
        return r2d2.loss_fn(params, params, sequences, weights, hparams, config)[0]

    # compiled: op by op, the unrolls' scans and the gradients' ops each compile on their own
    d_obs, d_state = jax.jit(jax.grad(loss_of, argnums=(0, 1)))(batch.steps.obs, batch.start_state)
    d_obs = np.asarray(d_obs)
    assert np.all(d_obs[:, : config.burn_in] == 0.0)
    assert np.all(np.abs(d_obs[:, config.burn_in :]).sum(axis=(0, 2)) > 0.0)
    assert all(np.all(np.asarray(leaf) == 0.0) for leaf in d_state)
    d_params = jax.jit(
        jax.grad(lambda p: r2d2.loss_fn(p, params, batch, weights, hparams, config)[0])
    )(params)
    assert all(np.all(np.isfinite(leaf)) for leaf in jax.tree.leaves(d_params))


# ---- the sequence replay -----------------------------------------------------------------------
def numbered_step(i: int, num_envs: int) -> Transition:
    """Step ``i`` of every env: obs ``100 i + env``, the state ``-(100 i + env)``."""
    ids = jnp.asarray([100.0 * i + env for env in range(num_envs)], jnp.float32)
    return Transition(
        obs=ids[:, None],
        action=jnp.zeros(num_envs, jnp.int32),
        reward=ids,
        next_obs=ids[:, None] + 1.0,
        terminated=jnp.zeros(num_envs, bool),
        truncated=jnp.zeros(num_envs, bool),
        policy_state=(-ids[:, None], -ids[:, None]),
    )


@pytest.mark.parametrize("prioritize", [False, True])
def test_sequences_are_whole_with_their_stored_start_states(prioritize):
    num_envs, length, period = 3, 5, 2
    example = jax.tree.map(lambda x: x[0], numbered_step(0, num_envs))
    memory = r2d2_parts.init(example, num_envs, length, period, capacity=30, prioritize=prioritize)
    add = jax.jit(lambda m, s: r2d2_parts.add(m, s, 0.9))
    for i in range(12):
        memory = add(memory, numbered_step(i, num_envs))
    rows = (
        memory.sequences.buffer
        if isinstance(memory.sequences, PrioritizedBuffer)
        else memory.sequences
    )
    # sequences end at steps 4, 6, 8, 10: they start at 0, 2, 4, 6
    assert int(rows.rows_filled) == 4
    starts = np.asarray(rows.data.steps.obs[:4, :, 0, 0])
    np.testing.assert_array_equal(starts, [[100.0 * s + e for e in range(3)] for s in (0, 2, 4, 6)])
    batch, weights, _ = r2d2_parts.sample(memory, jax.random.key(0), 64, 0.6)
    obs = np.asarray(batch.steps.obs[..., 0])  # [B, L]
    np.testing.assert_array_equal(np.diff(obs, axis=1), 100.0)  # consecutive steps of one env
    assert set(obs[:, 0] // 100) <= {0, 2, 4, 6}
    for leaf in batch.start_state:
        np.testing.assert_array_equal(np.asarray(leaf)[:, 0], -obs[:, 0])
    np.testing.assert_allclose(np.asarray(weights), 1.0)  # all new: equal priorities
    if prioritize:  # one sequence given a far larger priority is then (nearly) all one draws
        rows_drawn, columns = jnp.asarray([1]), jnp.asarray([2])
        memory = r2d2_parts.write_priorities(memory, (rows_drawn, columns), jnp.asarray([1e6]), 1.0)
        batch, _, _ = r2d2_parts.sample(memory, jax.random.key(1), 16, 0.6)
        assert np.mean(np.asarray(batch.steps.obs[:, 0, 0]) == 202.0) > 0.8


def test_the_loop_stores_the_state_each_action_was_chosen_with():
    """While warming up (no updates, fixed parameters) the states kept with the recent steps are
    the network's own unroll from the first of them, reset where episodes started. Then the same
    program (uniform replay) trains two more chunks with finite losses: the uniform half of
    ``test_a_few_chunks_train_with_finite_losses``, without a program of its own."""
    config = small_config(learning_starts=360, iterations_per_chunk=60, num_envs=3)
    hparams = r2d2.r2d2.default_hyperparams(ENV_ID)
    state = r2d2.init(jax.random.key(3), config, hparams)
    chunk = jax.jit(r2d2.train_chunk, static_argnums=1)
    state, metrics = chunk(state, config, hparams)
    assert int(metrics.updates) == 0 and not config.prioritized
    recent = state.buffer.recent  # [N, L, ...]
    starts = r2d2_parts.episode_starts(recent.terminated.T, recent.truncated.T).T
    first = jax.tree.map(lambda x: x[:, 0], recent.policy_state)
    carries, _ = step_by_step(state.agent.online, config, first, recent.obs, starts)
    for t in range(1, config.seq_len):
        for got, expected in zip(recent.policy_state, carries[t - 1], strict=True):
            expected = jnp.where(starts[:, t, None], 0.0, expected)
            np.testing.assert_allclose(np.asarray(got[:, t]), expected, rtol=1e-5, atol=1e-6)
    assert np.any(np.asarray(starts)), "no episode ended inside the window"
    for _ in range(2):  # updates from step 360 (iteration 120) on
        state, metrics = chunk(state, config, hparams)
    _assert_trained(state, metrics, 3 * 60 - config.learning_starts // config.num_envs)


# ---- the learner ---------------------------------------------------------------------------------
def test_it_is_registered_with_recipes_and_a_recurrent_policy():
    assert learners.ALGORITHMS["r2d2"] == "rl_jax.agents.r2d2:r2d2"
    assert rl_jax.r2d2 is r2d2.r2d2
    for env_id in (ENV_ID, "rl_jax/CartPole-v1"):
        config = r2d2.r2d2.default_config(env_id)
        assert (config.seq_len, config.burn_in, config.seq_period) == (20, 5, 10)
    carry = hooks(r2d2.r2d2).initial_policy_state(config)
    assert [x.shape for x in jax.tree.leaves(carry)] == [(64,), (64,)]
    with pytest.raises(ValueError, match="burn_in"):
        dataclasses.replace(config, burn_in=20)
    with pytest.raises(ValueError, match="learning_starts"):
        dataclasses.replace(config, learning_starts=10)


def _assert_trained(state, metrics, updates: int) -> None:
    assert int(metrics.updates) == updates
    assert np.isfinite(float(metrics.extra["loss"])) and np.isfinite(float(metrics.eval_return))
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(state.agent.online))


def test_a_few_chunks_train_with_finite_losses():
    """Prioritized sequences; uniform ones train on in
    ``test_the_loop_stores_the_state_each_action_was_chosen_with``."""
    config = small_config(prioritized=True, iterations_per_chunk=40)
    hparams = r2d2.r2d2.default_hyperparams(ENV_ID)
    state = r2d2.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(r2d2.train_chunk, static_argnums=1)
    for _ in range(2):
        state, metrics = chunk(state, config, hparams)
    _assert_trained(state, metrics, 2 * 40 - config.learning_starts // config.num_envs)


def test_a_run_trains_resumes_and_its_loaded_policy_keeps_its_state(tmp_path):
    config = {"hidden": (8,), "cell_size": 8, "seq_len": 6, "burn_in": 2, "seq_period": 3}
    config |= {"num_envs": 2, "batch_size": 4, "learning_starts": 12, "iterations_per_chunk": 25}
    common = dict(seeds=2, config=config, quiet=True)
    straight = rl_jax.train("r2d2", ENV_ID, total_steps=100, out=tmp_path / "a", **common)
    rl_jax.train("r2d2", ENV_ID, total_steps=50, out=tmp_path / "b", **common)
    resumed = rl_jax.resume(tmp_path / "b", total_steps=100, quiet=True)

    def rows(run):
        lines = (run.run_dir / "metrics.jsonl").read_text().splitlines()
        return [json.loads(line) for line in lines]

    keep = ("step", "seed", "eval_return", "train_return", "loss")
    assert [{k: r.get(k) for k in keep} for r in rows(resumed)] == [
        {k: r.get(k) for k in keep} for r in rows(straight)
    ]
    policy = rl_jax.load_policy(tmp_path / "a")
    obs = np.array([0.01, 0.0, -0.02, 0.0], np.float32)
    policy.reset()
    first = [int(policy(obs)) for _ in range(5)]
    policy.reset()
    assert [int(policy(obs)) for _ in range(5)] == first  # reset() restarts the state
    assert all(a in (0, 1) for a in first)


# ---- policy checkpoints (TD7's, as DQN's) ------------------------------------------------------
def _always(params, action: int):
    """``params`` changed so that the greedy action is ``action`` whatever the state and input."""
    head = params["params"]["advantage"]
    head = {"kernel": jnp.zeros_like(head["kernel"]), "bias": jax.nn.one_hot(action, 2)}
    return {"params": {**params["params"], "advantage": head}}


def test_policy_checkpoints_evaluate_the_checkpoint_and_explore_with_the_assessed_copy():
    config = small_config(policy_checkpoints=True, checkpoint_episodes_from=10)
    hparams = r2d2.r2d2.default_hyperparams(epsilon_start=0.0, epsilon_end=0.0).as_arrays()
    state = r2d2.init(jax.random.key(6), config, hparams)
    online = state.agent.online
    jax.tree.map(np.testing.assert_array_equal, state.agent.checkpoint.best, online)
    carry = jax.tree.map(lambda x: jnp.zeros((6, *x.shape)), r2d2.initial_carry(config))
    obs = jax.random.normal(jax.random.key(7), (6, 4))
    clock = r2d2.offpolicy.Clock(jnp.int32(0), jnp.int32(0), jnp.int32(0))

    def with_parts(best: int, assessed: int, now: int):
        parts = dict(best=_always(online, best), assessed=_always(online, assessed))
        return state.agent.replace(
            online=_always(online, now), checkpoint=state.agent.checkpoint.replace(**parts)
        )

    def explored(agent):
        key = jax.random.key(8)
        return r2d2.explore(agent, obs, carry, key, config, hparams, clock)[0].tolist()

    agent = with_parts(best=0, assessed=1, now=1)
    assert r2d2.act(agent, carry, obs, config)[0].tolist() == [0] * 6  # the checkpoint's
    policy = r2d2.r2d2.policy(state.replace(agent=agent), config)  # best/ and load_policy's
    assert int(policy(r2d2.initial_carry(config), obs[0])[0]) == 0
    assert explored(with_parts(best=1, assessed=0, now=1)) == [0] * 6  # the assessed copy's
    # One episode is an assessment before env step 10: the copy's return 7 passes (the score is
    # -1e8) and it becomes the checkpoint; the next copy is the online network.
    agent = with_parts(best=0, assessed=1, now=0)
    agent = agent.replace(checkpoint=agent.checkpoint.replace(counting=jnp.ones(2, bool)))
    done = jnp.array([True, False])
    agent = r2d2.observe(agent, None, jnp.full(2, 7.0), done, clock, config, hparams)
    assert r2d2.act(agent, carry, obs, config)[0].tolist() == [1] * 6
    assert float(agent.checkpoint.score) == 7.0
    jax.tree.map(np.testing.assert_array_equal, agent.checkpoint.assessed, agent.online)
    # Off (the recipe has it on): no checkpoint in the state, so runs without it keep their
    # structure, and observing is a no-op.
    plain = small_config(policy_checkpoints=False)
    plain_agent = r2d2.init(jax.random.key(6), plain, hparams).agent
    assert plain_agent.checkpoint is None
    assert (
        r2d2.observe(plain_agent, None, jnp.full(2, 7.0), done, clock, plain, hparams)
        is plain_agent
    )
    with pytest.raises(ValueError, match="checkpoint_episodes"):
        small_config(checkpoint_episodes=0)


# ---- slow: CartPoleNoVel-v1 at the recipe's budget ----------------------------------------------
@pytest.mark.slow
def test_r2d2_balances_cartpole_without_velocities_in_nine_of_ten_seeds(tmp_path):
    from rl_jax.run.runner import run
    from rl_jax.run.spec import RunSpec

    seeds, total = 10, 200_000
    spec = RunSpec(
        algorithm=r2d2.r2d2,
        env_id=ENV_ID,
        config=r2d2.default_config(ENV_ID),
        hparams=(r2d2.default_hyperparams(ENV_ID),),
        out=tmp_path / "run",
        seeds=seeds,
        total_steps=total,
        checkpoint_interval=0.0,
        log_interval=1e9,
    )
    assert run(spec, notify=lambda message: None).step >= total
    rows = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").open()]
    final = {r["seed"]: r["eval_return"] for r in rows if r["step"] >= total}
    assert len(final) == seeds
    assert sum(value >= 500.0 for value in final.values()) >= 9, final
