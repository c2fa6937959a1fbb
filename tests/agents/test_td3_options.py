"""TD3's TD7/CrossQ/SimBa options end to end: each trains a few hundred steps under the seed vmap
with finite results, alone and together (their maths is tested in test_td3_option_losses.py).

Every run here is 2 seeds in one program on ``rl_jax/Pendulum-v1`` with tiny networks: 2 chunks
of 200 env steps (2 envs), updates from step 100, 4 per iteration (Pendulum's recipe): 600
updates per seed. Compilation dominates each test.
"""

import dataclasses

import jax
import numpy as np
import pytest
import test_td3_reference

from rl_jax.agents.td3 import td3
from rl_jax.training import parallel, params, validation

# the reference run's tiny loop (kept as recorded there), with fewer eval episodes
TINY = {**test_td3_reference.TINY, "num_eval_envs": 2}


def train(chunks: int = 2, hparams: dict | None = None, **config_overrides):
    """``(state [1, 2, ...] on the host, [chunk metrics [1, 2]])`` of a tiny 2-seed run."""
    config = td3.default_config("rl_jax/Pendulum-v1", **{**TINY, **config_overrides})
    stacked = params.stack([td3.default_hyperparams("rl_jax/Pendulum-v1", **(hparams or {}))])
    program = parallel.Program(td3, config, 1, 2, devices=jax.devices()[:1])
    state = program.init(parallel.seed_keys([0, 1]), stacked)
    history = []
    for _ in range(chunks):
        state, metrics = program.train_chunk(state, stacked)
        history.append(program.gather(metrics))
    return program.unpad(state, stacked), history


def assert_trained_and_finite(state, history):
    """Updates ran, and every float of the state and of the metrics is finite."""
    assert int(np.asarray(history[-1].updates).max()) > 0
    for leaf in jax.tree.leaves(state.agent):
        if np.issubdtype(np.asarray(leaf).dtype, np.floating):
            assert np.all(np.isfinite(leaf))
    for metrics in history:
        assert np.all(np.isfinite(metrics.eval_return))
        for name, value in metrics.extra.items():
            assert not np.any(np.isinf(value)), name


def test_layer_norm_critics_and_actor_train():
    state, history = train(critic_norm="layer", actor_norm="layer", critic_activation="elu")
    assert "LayerNorm_1" in state.agent.critics["params"]["MLP_0"]
    assert "LayerNorm_0" in state.agent.actor["params"]["MLP_0"]
    assert_trained_and_finite(state, history)


@pytest.mark.parametrize(
    "bad",
    [{"critic_norm": "group"}, {"actor_norm": "weight"}, {"critic_activation": "gelu"}],
)
def test_unknown_option_values_are_refused(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        td3.default_config("rl_jax/Pendulum-v1", **bad)


def test_every_config_field_and_hyperparameter_has_help_text():
    from rl_jax.run import field_docs

    config = td3.default_config("rl_jax/Pendulum-v1")
    assert field_docs.undocumented_fields(config) == ["env_id"]  # not a flag: the script's env
    assert field_docs.undocumented_fields(td3.default_hyperparams()) == []


def test_lap_trains_with_a_prioritized_buffer():
    state, history = train(lap=True, hparams={"lap_alpha": 0.4})
    tree = state.buffer
    leaves = np.asarray(tree.sums)[..., tree.sums.shape[-1] // 2 :]
    # Every stored transition has priority max(|td|, 1)^alpha >= 1 (400 of 1,000 slots filled).
    assert np.all(np.sum(leaves >= 1.0 - 1e-6, axis=-1) == 400)
    assert np.all(np.asarray(tree.max_priority) > 1.0)
    assert_trained_and_finite(state, history)


SALE = {"sale": True, "embedding_dim": 8, "embedding_hidden": (16,)}


def test_sale_trains_its_encoder_and_moves_the_fixed_copies():
    state, history = train(**SALE)
    encoders = state.agent.encoders
    assert np.all(np.isfinite(history[-1].extra["encoder_loss"]))
    parts = (encoders.online, encoders.fixed, encoders.fixed_target)
    online, fixed, target = (jax.tree.leaves(part)[0] for part in parts)
    assert not np.allclose(online, fixed) and not np.allclose(fixed, target)
    assert_trained_and_finite(state, history)


def test_sale_refuses_n_step_returns():
    with pytest.raises(ValueError, match="n_step 1"):
        td3.default_config("rl_jax/Pendulum-v1", sale=True, n_step=3)


SIMBA = {"network": "simba", "actor_hidden": (16,), "critic_hidden": (16, 16)}


def test_simba_trains_on_observations_standardised_by_running_statistics():
    state, history = train(**SIMBA)
    stats = state.agent.obs_stats
    # Every observation acted on (400 env steps per seed) is in the statistics.
    np.testing.assert_allclose(stats.count, 1e-4 + 400, rtol=1e-6)
    # Pendulum's obs (cos, sin, angular velocity): the mean of cos/sin stays within [-1, 1].
    assert np.all(np.abs(stats.mean[..., :2]) <= 1.0) and np.all(stats.var > 0.0)
    assert "Simba_0" in state.agent.actor["params"]
    assert_trained_and_finite(state, history)


def test_simba_policy_reads_standardised_observations():
    from rl_jax.agents.td3 import make_networks
    from rl_jax.training import normalization

    config = td3.default_config("rl_jax/Pendulum-v1", **{**TINY, **SIMBA})
    state = td3.init(jax.random.key(0), config, td3.default_hyperparams())
    stats = normalization.RunningStats(
        count=np.float32(10.0), mean=np.array([1.0, -1.0, 2.0], np.float32), var=np.full(3, 4.0)
    )
    agent = state.agent.replace(obs_stats=stats)
    obs = np.array([[3.0, 1.0, 2.0]], np.float32)
    got = td3.policy(state.replace(agent=agent), config)(obs)
    standardised = (obs - stats.mean[None]) / np.sqrt(stats.var[None] + 1e-8)
    expected = make_networks(config).actor.apply(agent.actor, standardised)
    np.testing.assert_allclose(got, expected, rtol=1e-6)


def test_normalize_obs_standardises_the_mlps_inputs_with_the_same_statistics():
    from rl_jax.agents.td3 import make_networks

    state, history = train(normalize_obs=True)
    stats = state.agent.obs_stats
    np.testing.assert_allclose(stats.count, 1e-4 + 400, rtol=1e-6)  # every obs acted on
    assert np.all(np.abs(stats.mean[..., :2]) <= 1.0) and np.all(stats.var > 0.0)
    assert "Simba_0" not in state.agent.actor["params"]  # the paper's MLP
    assert_trained_and_finite(state, history)
    # the exported policy reads standardised observations
    config = td3.default_config("rl_jax/Pendulum-v1", **{**TINY, "normalize_obs": True})
    fresh = td3.init(jax.random.key(0), config, td3.default_hyperparams())
    stats = jax.tree.map(lambda leaf: leaf[0, 0], stats)  # seed 0's, after 400 env steps
    agent = fresh.agent.replace(obs_stats=stats)
    obs = np.array([[3.0, 1.0, 2.0]], np.float32)
    got = td3.policy(fresh.replace(agent=agent), config)(obs)
    standardised = np.clip((obs - stats.mean[None]) / np.sqrt(stats.var[None] + 1e-8), -10, 10)
    expected = make_networks(config).actor.apply(agent.actor, standardised)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    assert not td3.default_config("rl_jax/Pendulum-v1").standardizes_obs


def test_simba_refuses_unequal_widths_and_extra_norms():
    with pytest.raises(ValueError, match="one width"):
        td3.default_config("rl_jax/Pendulum-v1", network="simba", critic_hidden=(16, 8))
    with pytest.raises(ValueError, match="own LayerNorms"):
        td3.default_config("rl_jax/Pendulum-v1", network="simba", critic_norm="layer")


def test_sale_lap_simba_and_hard_targets_compose():
    state, history = train(lap=True, target_update_period=50, value_clipping=True, **SALE, **SIMBA)
    agent = state.agent
    assert agent.obs_stats is not None and agent.encoders is not None
    assert np.all(agent.value_range.low < agent.value_range.high)  # renewed from [0, 0]
    assert "Simba_0" in agent.critics["params"] and "Dense_0" in agent.critics["params"]
    # 600 updates per seed, a copy at every 50th: the last update was a copy.
    jax.tree.map(np.testing.assert_array_equal, agent.target_critics, agent.critics)
    assert_trained_and_finite(state, history)


def test_policy_checkpoints_evaluate_the_checkpoint_not_the_online_actor():
    from rl_jax.agents import td3 as td3_module

    # Hard target copies every 1,000 updates, never reached: the target actor stays the initial.
    state, history = train(4, policy_checkpoints=True, target_update_period=1000)
    checkpoint = state.agent.checkpoint
    # Pendulum's 200-step episodes end together in both envs at env steps 400 and 800 (2 envs);
    # updates start at 100, so the first counted episodes are those from 400 to 800: they pass
    # (nothing to beat yet) and the copy taken at 400, after 600 updates, is the checkpoint.
    np.testing.assert_array_equal(checkpoint.episodes, 0)
    assert np.all(checkpoint.score > -1e8) and np.all(checkpoint.score < 0.0)
    leaf = lambda tree: np.asarray(jax.tree.leaves(tree)[0])  # noqa: E731
    initial = leaf(state.agent.target_actor)
    assert not np.allclose(leaf(checkpoint.best.actor), initial)
    assert not np.allclose(leaf(checkpoint.best.actor), leaf(state.agent.actor))
    # A new copy was taken at 400, before that iteration's update moved the online actor.
    assert not np.allclose(leaf(checkpoint.assessed.actor), leaf(checkpoint.best.actor))
    config = td3.default_config("rl_jax/Pendulum-v1", **TINY, policy_checkpoints=True)
    one = jax.tree.map(lambda x: x[0, 0], state.agent)
    obs = np.zeros((1, 3), np.float32)
    expected = td3_module.act_with(td3_module.make_networks(config), one.checkpoint.best, obs)
    np.testing.assert_array_equal(td3.policy(state.replace(agent=one), config)(obs), expected)
    assert_trained_and_finite(state, history)


CROSSQ = {
    "critic_norm": "batch_renorm",
    "target_networks": False,
    "renorm_warmup": 50,
    "adam_b1": 0.5,
}


def test_crossq_trains_without_target_networks_and_keeps_its_statistics():
    state, history = train(**CROSSQ)
    agent = state.agent
    first = agent.critic_stats["MLP_0"]["BatchRenorm_0"]
    np.testing.assert_array_equal(first["steps"], 600)  # one training pass per critic update
    assert np.all(first["var"] > 0.0)
    # No target networks: the target fields never moved from the initial parameters.
    initial = jax.tree.leaves(agent.target_critics)[0]
    assert not np.allclose(initial, jax.tree.leaves(agent.critics)[0])
    for opt in (agent.critic_opt, agent.actor_opt):  # CrossQ's Adam, recorded in the state
        np.testing.assert_array_equal(opt.hyperparams["b1"], 0.5)
    assert_trained_and_finite(state, history)


def test_crossq_sale_lap_and_policy_checkpoints_compose():
    state, history = train(
        4, lap=True, policy_checkpoints=True, target_update_period=50, **SALE, **CROSSQ
    )
    agent = state.agent
    assert agent.critic_stats is not None and agent.encoders is not None
    assert np.all(agent.checkpoint.score > -1e8)  # a checkpoint passed (see the test above)
    assert_trained_and_finite(state, history)


def test_batch_renorm_is_for_the_critics_only():
    with pytest.raises(ValueError, match="actor_norm"):
        td3.default_config("rl_jax/Pendulum-v1", actor_norm="batch_renorm")


def test_the_options_state_checkpoints_and_a_resumed_run_ends_bit_identical(tmp_path):
    """SALE's encoders, the prioritized replay, the policy checkpoint and the batch statistics
    all go through orbax: a run stopped after 2 chunks and resumed ends as one never stopped,
    and its kept best policy loads."""
    import dataclasses

    from run_helpers import leaves_bytes

    import rl_jax
    from rl_jax.run.runner import run
    from rl_jax.run.spec import RunSpec

    options = {**SALE, **CROSSQ, "lap": True, "policy_checkpoints": True}
    config = td3.default_config("rl_jax/Pendulum-v1", **TINY, **options, target_update_period=50)
    spec = RunSpec(
        algorithm=td3,
        env_id="rl_jax/Pendulum-v1",
        config=config,
        hparams=(td3.default_hyperparams("rl_jax/Pendulum-v1"),),
        out=tmp_path / "full",
        seeds=2,
        total_steps=600,
        checkpoint_interval=0.0,
        log_interval=1e9,
    )
    quiet = lambda message: None  # noqa: E731
    full = run(spec, notify=quiet)
    stopped = dataclasses.replace(spec, out=tmp_path / "stopped", total_steps=400)
    assert run(stopped, notify=quiet).step == 400
    resumed = run(dataclasses.replace(stopped, total_steps=600, resume=True), notify=quiet)
    assert resumed.step == 600
    assert leaves_bytes(resumed.state) == leaves_bytes(full.state)
    policy = rl_jax.load_policy(tmp_path / "stopped", seed=1)
    assert np.all(np.isfinite(policy(np.zeros(3, np.float32))))


def test_the_td7_recipe_is_td7s_published_settings_and_trains():
    from rl_jax.agents.td3 import TD7_CONFIG, TD7_HPARAMS

    config = td3.default_config("rl_jax/HalfCheetah-v5", **TD7_CONFIG)
    assert config.sale and config.lap and config.policy_checkpoints and config.value_clipping
    assert (config.target_update_period, config.embedding_dim, config.embedding_hidden) == (
        250,
        256,
        (256, 256),
    )
    assert (config.num_envs, config.updates_per_iteration, config.batch_size) == (1, 1, 256)
    assert (config.actor_hidden, config.critic_hidden) == ((256, 256), (256, 256))
    assert (config.actor_activation, config.critic_activation) == ("relu", "elu")
    assert (config.checkpoint_episodes, config.checkpoint_episodes_from) == (20, 750_000)
    hparams = td3.default_hyperparams(**TD7_HPARAMS).to_dict()
    rates = [hparams[name] for name in ("actor_lr", "critic_lr", "encoder_lr")]
    assert rates == pytest.approx([3e-4] * 3)
    assert hparams["lap_alpha"] == pytest.approx(0.4)
    assert td3.default_config("rl_jax/HalfCheetah-v5", "td7") == config
    assert validation.out_of_range(config, td3) is None
    assert validation.out_of_range(td3.default_hyperparams(**TD7_HPARAMS), td3) is None
    refused = validation.out_of_range(td3.default_hyperparams(lap_alpha=1.5), td3)
    assert refused == "--lap-alpha must be in [0, 1], got 1.5"
    # The same options on tiny networks train (the TD7 loop itself is too slow for a test).
    tiny = {**TD7_CONFIG, **TINY, **SALE, "target_update_period": 50}
    state, history = train(4, hparams=TD7_HPARAMS, **tiny)
    assert np.all(state.agent.checkpoint.score > -1e8)
    assert_trained_and_finite(state, history)


def test_the_td7_cpu_recipe_is_td7s_options_in_the_cpu_loop_at_its_sizes():
    from rl_jax.agents.td3 import TD7_CONFIG, TD7_CPU_CONFIG, TD7_CPU_HPARAMS, TD7_HPARAMS

    cpu = td3.default_config("rl_jax/HalfCheetah-v5", **TD7_CPU_CONFIG)
    default = td3.default_config("rl_jax/HalfCheetah-v5")
    td7 = td3.default_config("rl_jax/HalfCheetah-v5", **TD7_CONFIG)
    loop = ("num_envs", "updates_per_iteration", "batch_size", "learning_starts")
    sizes = ("actor_hidden", "critic_hidden")
    for name in dataclasses.fields(cpu):
        field = name.name
        if field in loop + sizes + ("iterations_per_chunk",):
            assert getattr(cpu, field) == getattr(default, field), field
        elif field in ("embedding_dim", "embedding_hidden"):
            assert getattr(cpu, field) in (128, (128, 128)), field
        else:
            assert getattr(cpu, field) == getattr(td7, field), field
    assert TD7_CPU_HPARAMS == TD7_HPARAMS
    assert td3.default_config("rl_jax/HalfCheetah-v5", "td7-cpu") == cpu
