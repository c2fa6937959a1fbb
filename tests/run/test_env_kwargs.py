"""An env's constructor keywords in a run (``--env-kwargs``, the configs' ``env_kwargs``): parsed
as written in a call, refused with one line when wrong, kept in the run's config, and used by
training, evaluation and loaded policies alike."""

import json

import numpy as np
import pytest

import rl_jax
from rl_jax import envs
from rl_jax.agents.dqn import dqn
from rl_jax.agents.reinforce import reinforce
from rl_jax.agents.td3 import td3
from rl_jax.errors import UsageError
from rl_jax.run.policy import LoadedPolicy
from rl_jax.training.params import dataclass_from_dict, dataclass_to_dict


def test_keywords_read_as_in_a_call():
    assert envs.parse_keywords("") == {} and envs.parse_keywords("  ") == {}
    parsed = envs.parse_keywords(
        "include_cfrc_ext_in_observation=False, reset_noise_scale=0.05, "
        "contact_force_range=(-1.0, 1.0), xml_file='ant.xml', backend=mjx"
    )
    assert parsed == {
        "include_cfrc_ext_in_observation": False,
        "reset_noise_scale": 0.05,
        "contact_force_range": (-1.0, 1.0),
        "xml_file": "ant.xml",
        "backend": "mjx",  # a bare word is its own string
    }
    assert type(parsed["include_cfrc_ext_in_observation"]) is bool


@pytest.mark.parametrize(
    "text, message",
    [
        ("a=1,", None),  # a trailing comma is valid Python
        ("a=", "must read name=value"),
        ("True", "must read name=value"),
        ("a=1, a=2", "'a' is given twice"),
        ("a=open('x')", "a: open\\('x'\\) is not a Python literal"),
        ("**b", "must read name=value"),
    ],
)
def test_bad_keywords_are_one_line(text, message):
    if message is None:
        assert envs.parse_keywords(text) == {"a": 1}
        return
    with pytest.raises(ValueError, match=message) as error:
        envs.parse_keywords(text)
    assert "\n" not in str(error.value)


def test_configs_build_the_env_with_them_and_keep_the_recipe():
    plain = dqn.default_config("rl_jax/CartPole-v1")
    config = dqn.default_config("rl_jax/CartPole-v1", env_kwargs="sutton_barto_reward=True")
    assert config.make_env().sutton_barto_reward and not plain.make_env().sutton_barto_reward
    assert config.hidden == plain.hidden and config.n_step == plain.n_step  # the recipe's
    # through the run's config.json and back
    saved = json.loads(json.dumps(dataclass_to_dict(config)))
    assert dataclass_from_dict(dqn.default_config("rl_jax/CartPole-v1"), saved) == config
    # and a run saved before the field existed reads as no keywords
    del saved["env_kwargs"]
    assert dataclass_from_dict(plain, saved).env_kwargs == ""
    assert reinforce.default_config(
        "rl_jax/CartPole-v1", env_kwargs="kinematics_integrator='semi-implicit'"
    ).make_env().kinematics_integrator == ("semi-implicit")
    ant = td3.default_config("rl_jax/Ant-v5", env_kwargs="include_cfrc_ext_in_observation=False")
    assert ant.make_env().observation_space().shape == (27,)
    assert ant.actor_hidden == td3.default_config("rl_jax/Ant-v5").actor_hidden
    with pytest.raises(ValueError, match="not a Python literal"):
        td3.default_config("rl_jax/Ant-v5", env_kwargs="x=y()")
    with pytest.raises(ValueError, match="frame_size is a config field here: --frame-size"):
        dqn.default_config("rl_jax/CartPolePixels-v1", env_kwargs="frame_size=42")


# CartPole with Sutton and Barto's reward (0 per step, -1 when the pole falls): every return of
# a run that used the keywords is <= 0, where CartPole's own are >= 1.
TINY_DQN = {
    "num_envs": 2,
    "updates_per_iteration": 1,
    "iterations_per_chunk": 50,
    "learning_starts": 50,
    "batch_size": 16,
    "buffer_size": 500,
    "num_eval_envs": 2,
    "hidden": (16,),
    "env_kwargs": "sutton_barto_reward=True",
}


def test_training_evaluation_and_loaded_policies_use_them(tmp_path):
    run = rl_jax.train(
        "dqn",
        "rl_jax/CartPole-v1",
        total_steps=200,
        out=tmp_path / "run",
        config=TINY_DQN,
        quiet=True,
    )
    assert run.results.step == 200 and np.all(run.results.returns <= 0.0)
    saved = json.loads((run.run_dir / "config.json").read_text())
    assert saved["identity"]["config"]["env_kwargs"] == "sutton_barto_reward=True"
    assert all(score <= 0.0 for score in run.evaluate(episodes=2).values())
    loaded = LoadedPolicy(run.run_dir, 0, None, "latest")
    assert loaded.env().sutton_barto_reward  # what load_policy, render and --gif act in
    resumed = rl_jax.resume(run.run_dir, total_steps=300, quiet=True)
    assert resumed.results.step == 300 and np.all(resumed.results.returns <= 0.0)


def test_an_unknown_keyword_is_one_clear_error(tmp_path):
    with pytest.raises(UsageError, match="cannot run rl_jax/CartPole-v1: .*no_such"):
        rl_jax.train(
            "dqn",
            "rl_jax/CartPole-v1",
            total_steps=100,
            out=tmp_path / "x",
            config={**TINY_DQN, "env_kwargs": "no_such=1"},
            quiet=True,
        )
    assert not (tmp_path / "x").exists()
