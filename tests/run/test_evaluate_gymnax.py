"""``python -m rl_jax.run.evaluate RUN --gymnax``: a MinAtar run's policies replayed in gymnax's own
env through gymnax's own ``reset`` and ``step``, on the episode keys of our evaluation, so the
same policy gives the same returns in both; each observation given to the policy as our env gives
it; one error line for a run that gymnax cannot replay."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax
from rl_jax import envs
from rl_jax.errors import UsageError
from rl_jax.run import evaluate
from rl_jax.run.policy import LoadedPolicy

gymnax = pytest.importorskip("gymnax")

BREAKOUT = "rl_jax/Breakout-MinAtar"
FREEWAY = "rl_jax/Freeway-MinAtar"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A tiny PQN run on Breakout: one chunk of 16 env steps."""
    config = {"num_envs": 4, "num_steps": 4, "num_minibatches": 2, "num_epochs": 1}
    config |= {"iterations_per_chunk": 1, "num_eval_envs": 1, "hidden": (16,)}
    config |= {"conv_layers": (4, 3, 1)}
    out = tmp_path_factory.mktemp("gymnax") / "run"
    return rl_jax.train("pqn", BREAKOUT, total_steps=16, out=out, config=config, quiet=True).run_dir


def always_up(obs: jax.Array) -> jax.Array:
    """Freeway's chicken sent up (actions: stay, up, down): how often it crosses depends on the
    cars, which the env draws from its reset and step keys."""
    return jnp.int32(1)


def test_same_keys_give_our_envs_returns_in_gymnax():
    """Played to gymnax's own end (its step limit, which the run's keyword sets), the returns
    are those of our env's evaluation on the same keys: they score, and differently in each
    episode, as Freeway draws its cars from the reset and step keys."""
    keywords = {"max_steps_in_episode": 150}
    name, env, params = evaluate.gymnax_twin(FREEWAY, {**keywords, "sticky_actions": 0.0})
    ours = envs.make(FREEWAY, **keywords)
    observe = evaluate.observation_as_ours(env, params, ours.observation_space())
    theirs = evaluate.gymnax_returns(always_up, env, params, 8, key=3, observe=observe)
    expected = evaluate.returns_of(ours, always_up, jax.random.key(3), 8)
    assert name == "Freeway-MinAtar"
    np.testing.assert_array_equal(theirs, expected)
    assert theirs.max() > 0 and len(set(theirs.tolist())) > 2


def test_the_policy_sees_gymnaxs_observations_as_our_env_gives_them(run_dir):
    """The loaded policy's env and gymnax's, stepped with the same keys and the policy's actions
    through one episode: gymnax's observation, as ``observation_as_ours`` gives it to the policy,
    is ours, and the rewards and the episode's end are the same."""
    loaded = LoadedPolicy(run_dir, seed=0)
    ours, act = loaded.env(), jax.jit(loaded.act())
    _, env, params = evaluate.gymnax_twin(loaded.env_id, {})
    observe = jax.jit(evaluate.observation_as_ours(env, params, ours.observation_space()))
    state, ts = ours.reset(jax.random.key(5))
    obs, gymnax_state = env.reset(jax.random.key(5), params)
    assert obs.shape == ts.obs.shape == (10, 10, 4) and ts.obs.dtype == jnp.float32
    assert observe(obs).dtype == ts.obs.dtype
    np.testing.assert_array_equal(observe(obs), ts.obs)
    step = jax.jit(ours.step)
    for t in range(ours.max_episode_steps):
        action, key = act(ts.obs), jax.random.key(100 + t)
        state, ts = step(key, state, action)
        _, gymnax_state, reward, terminated, truncated, info = env.step(
            key, gymnax_state, action, params
        )
        # gymnax's obs after an end is the next episode's; the one that ended it is in its info
        np.testing.assert_array_equal(observe(info["final_observation"]), ts.obs, f"step {t}")
        assert float(reward) == float(ts.reward)
        assert (bool(terminated), bool(truncated)) == (bool(ts.terminated), bool(ts.truncated))
        if bool(terminated) or bool(truncated):
            break
    assert bool(ts.terminated) and t > 0


def test_command_line_replays_every_seed_in_gymnax_and_prints_the_table(
    run_dir, capsys, monkeypatch
):
    played = []

    def spy(*args, **kwargs):
        played.append(gymnax_returns(*args, **kwargs))
        return played[-1]

    gymnax_returns = evaluate.gymnax_returns
    monkeypatch.setattr(evaluate, "gymnax_returns", spy)
    assert evaluate.main([str(run_dir), "--gymnax", "--episodes", "3"]) == 0
    out = capsys.readouterr().out
    assert "each policy on 3 fresh episodes of gymnax's Breakout-MinAtar" in out
    assert "     0  best" in out
    (ours,) = evaluate.evaluate_run(run_dir, episodes=3)
    (replayed,) = played
    np.testing.assert_array_equal(replayed, ours.returns)


def test_runs_gymnax_cannot_replay_are_refused():
    for env_id in ("rl_jax/CartPole-v1", "gymnasium:Breakout-MinAtar"):
        with pytest.raises(UsageError, match="is not a gymnax env"):
            evaluate.gymnax_name(env_id)
    with pytest.raises(UsageError, match="sticky_actions=0.1.* no sticky actions"):
        evaluate.gymnax_twin("rl_jax/Asterix-MinAtar", {"sticky_actions": 0.1})
    name, _, params = evaluate.gymnax_twin("rl_jax/Asterix-MinAtar", {"ramping": False})
    assert name == "Asterix-MinAtar" and not bool(params.ramping)
    with pytest.raises(UsageError, match="choose one"):
        evaluate.evaluate_run(evaluate.Path("unused"), gymnasium=True, gymnax=True)
