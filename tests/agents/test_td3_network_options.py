"""TD3's network settings end to end (LayerNorm, SimBa blocks, standardised observations): each
trains a few hundred steps under the seed vmap with finite results; bad values are refused.

Every run here is 2 seeds in one program on ``rl_jax/Pendulum-v1`` with tiny networks: 2 chunks
of 200 env steps (2 envs), updates from step 100, 4 per iteration (Pendulum's recipe): 600
updates per seed. Compilation dominates each test. ``test_td7.py`` and ``test_crossq.py`` train
their learners with the helpers here.
"""

import dataclasses
import functools

import jax
import numpy as np
import pytest
import test_td3_reference

from rl_jax.agents.td3 import make_networks, td3
from rl_jax.training import normalization, parallel, params
from rl_jax.training.algorithm import Algorithm

ENV_ID = "rl_jax/Pendulum-v1"
# The reference run's tiny loop (kept as recorded there), with fewer eval episodes, and
# Pendulum's 4 updates per iteration written out for the learners that have no Pendulum recipe.
TINY = {**test_td3_reference.TINY, "num_eval_envs": 2, "updates_per_iteration": 4}


def train(
    chunks: int = 2, hparams: dict | None = None, algorithm: Algorithm = td3, **config_overrides
):
    """``([state [1, 2, ...] on the host before the first chunk and after each], [chunk metrics
    [1, 2]])`` of a tiny 2-seed run of ``algorithm``."""
    config = algorithm.default_config(ENV_ID, **{**TINY, **config_overrides})
    stacked = params.stack([algorithm.default_hyperparams(ENV_ID, **(hparams or {}))])
    program = parallel.Program(algorithm, config, 1, 2, devices=jax.devices()[:1])
    state = program.init(parallel.seed_keys([0, 1]), stacked)
    states, history = [program.unpad(state, stacked)], []
    for _ in range(chunks):
        state, metrics = program.train_chunk(state, stacked)
        states.append(program.unpad(state, stacked))
        history.append(program.gather(metrics))
    return states, history


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


def assert_resumes_bit_identical(algorithm: Algorithm, tmp_path, **config_overrides):
    """A run of ``algorithm`` stopped after 2 chunks and resumed ends as one never stopped (the
    whole state goes through orbax), and its kept best policy loads. Runs the ``train`` config of
    the same overrides, so the runner reuses that compiled program."""
    from run_helpers import leaves_bytes

    import rl_jax
    from rl_jax.run.runner import run
    from rl_jax.run.spec import RunSpec

    spec = RunSpec(
        algorithm=algorithm,
        env_id=ENV_ID,
        config=algorithm.default_config(ENV_ID, **{**TINY, **config_overrides}),
        hparams=(algorithm.default_hyperparams(ENV_ID),),
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


# LayerNorm in both networks and standardised MLP inputs: they compose (the statistics
# standardise what enters the first layer, LayerNorm sits inside each hidden one), so one run, one
# compiled program, serves the tests of both, each asserting its own part.
LAYER_NORM_STANDARDISED = {
    "critic_norm": "layer",
    "actor_norm": "layer",
    "critic_activation": "elu",
    "normalize_obs": True,
}


@functools.cache
def layer_norm_standardised_run():
    """``train()`` of LAYER_NORM_STANDARDISED, made once for the tests that read it."""
    return train(**LAYER_NORM_STANDARDISED)


def test_layer_norm_critics_and_actor_train():
    states, history = layer_norm_standardised_run()
    state = states[-1]
    assert "LayerNorm_1" in state.agent.critics["params"]["MLP_0"]
    assert "LayerNorm_0" in state.agent.actor["params"]["MLP_0"]
    assert_trained_and_finite(state, history)


@pytest.mark.parametrize(
    "bad",
    [
        {"critic_norm": "group"},
        {"actor_norm": "weight"},
        {"critic_activation": "gelu"},
        # batch renormalisation is CrossQ's (its own learner), for no network of TD3's
        {"critic_norm": "batch_renorm"},
        {"actor_norm": "batch_renorm"},
        {"network": "resnet"},
    ],
)
def test_unknown_option_values_are_refused(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        td3.default_config(ENV_ID, **bad)


def test_every_config_field_and_hyperparameter_has_help_text():
    from rl_jax.run import field_docs

    config = td3.default_config(ENV_ID)
    assert field_docs.undocumented_fields(config) == ["env_id"]  # not a flag: the script's env
    assert field_docs.undocumented_fields(td3.default_hyperparams()) == []


SIMBA = {"network": "simba", "actor_hidden": (16,), "critic_hidden": (16, 16)}


def test_simba_trains_on_observations_standardised_by_running_statistics():
    states, history = train(**SIMBA)
    state = states[-1]
    stats = state.agent.obs_stats
    # Every observation acted on (400 env steps per seed) is in the statistics.
    np.testing.assert_allclose(stats.count, 1e-4 + 400, rtol=1e-6)
    # Pendulum's obs (cos, sin, angular velocity): the mean of cos/sin stays within [-1, 1].
    assert np.all(np.abs(stats.mean[..., :2]) <= 1.0) and np.all(stats.var > 0.0)
    assert "Simba_0" in state.agent.actor["params"]
    assert "Simba_0" in state.agent.critics["params"]
    assert_trained_and_finite(state, history)


def test_simba_policy_reads_standardised_observations():
    config = td3.default_config(ENV_ID, **{**TINY, **SIMBA})
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
    states, history = layer_norm_standardised_run()
    state = states[-1]
    stats = state.agent.obs_stats
    np.testing.assert_allclose(stats.count, 1e-4 + 400, rtol=1e-6)  # every obs acted on
    assert np.all(np.abs(stats.mean[..., :2]) <= 1.0) and np.all(stats.var > 0.0)
    assert "Simba_0" not in state.agent.actor["params"]  # the paper's MLP
    assert_trained_and_finite(state, history)
    # the exported policy reads standardised observations
    config = td3.default_config(ENV_ID, **{**TINY, **LAYER_NORM_STANDARDISED})
    fresh = td3.init(jax.random.key(0), config, td3.default_hyperparams())
    stats = jax.tree.map(lambda leaf: leaf[0, 0], stats)  # seed 0's, after 400 env steps
    agent = fresh.agent.replace(obs_stats=stats)
    obs = np.array([[3.0, 1.0, 2.0]], np.float32)
    got = td3.policy(fresh.replace(agent=agent), config)(obs)
    standardised = np.clip((obs - stats.mean[None]) / np.sqrt(stats.var[None] + 1e-8), -10, 10)
    expected = make_networks(config).actor.apply(agent.actor, standardised)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    assert not td3.default_config(ENV_ID).standardizes_obs


def test_simba_refuses_unequal_widths_and_extra_norms():
    with pytest.raises(ValueError, match="one width"):
        td3.default_config(ENV_ID, network="simba", critic_hidden=(16, 8))
    with pytest.raises(ValueError, match="own LayerNorms"):
        td3.default_config(ENV_ID, network="simba", critic_norm="layer")
