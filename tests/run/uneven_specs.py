"""The runs of 5 seeds that tests/run/test_uneven_devices.py compares across device counts."""

import dataclasses
from pathlib import Path

import fake_algorithm as fake

from rl_jax.agents.sac import sac
from rl_jax.agents.td3 import td3
from rl_jax.run.spec import RunSpec

SEEDS = 5  # divides over neither 2 nor 4 devices
TD3_ENV = "rl_jax/Pendulum-v1"
SAC_ENV = "rl_jax/HalfCheetah-v5"  # stepped by the MuJoCo C op inside the program


# The tiny off-policy loop both learners run: 8 x 8 networks, 50 env steps per chunk (2 envs x 25
# iterations), updates from step 50, one evaluation episode per seed.
TINY_LOOP = dict(
    num_envs=2,
    iterations_per_chunk=25,
    learning_starts=50,
    batch_size=16,
    buffer_size=200,
    num_eval_envs=1,
    actor_hidden=(8, 8),
    critic_hidden=(8, 8),
)


def tiny_td3_config():
    """TD3 on the pendulum in the tiny loop."""
    return dataclasses.replace(td3.default_config(TD3_ENV), **TINY_LOOP)


def tiny_sac_config():
    """SAC on half cheetah in the tiny loop (one update per env step), each evaluation one full
    1,000-step episode per seed."""
    return dataclasses.replace(sac.default_config(SAC_ENV), **TINY_LOOP, updates_per_iteration=1)


def spec_for(learner: str, out: Path, total_steps: int, resume: bool = False) -> RunSpec:
    """The 5-seed run of ``learner`` ("fake", "td3" or "sac"), checkpointed after every chunk."""
    if learner == "fake":
        algorithm, env_id, config = fake, fake.ENV_ID, fake.default_config()
        hparams = fake.default_hyperparams()
    elif learner == "sac":
        algorithm, env_id, config = sac, SAC_ENV, tiny_sac_config()
        hparams = sac.default_hyperparams(SAC_ENV)
    else:
        algorithm, env_id, config = td3, TD3_ENV, tiny_td3_config()
        hparams = td3.default_hyperparams(TD3_ENV)
    return RunSpec(
        algorithm,
        env_id,
        config,
        (hparams,),
        out,
        seeds=SEEDS,
        total_steps=total_steps,
        resume=resume,
        checkpoint_interval=0.0,
        log_interval=1e9,
    )
