"""The page "Your own environment" (docs/own_env.md): its code block is
``examples/hover_rocket.py``, the env it defines integrates exactly with RK4 and vmaps over params,
and its command line trains TD3 on it (with a tiny budget) and resumes in a fresh process that
imports the module again."""

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from child_env import without_root

from rl_jax import envs

ROOT = Path(__file__).resolve().parent.parent
ENV_ID = "examples.hover_rocket:examples/HoverRocket-v0"
TINY_FLAGS = [
    "--num-envs=2", "--updates-per-iteration=2", "--iterations-per-chunk=50",
    "--learning-starts=100", "--batch-size=32", "--buffer-size=1000", "--num-eval-envs=2",
    "--actor-hidden=16,16", "--critic-hidden=16,16", "--seeds=2", "--log-interval=0",
]  # fmt: skip


def _section() -> str:
    page = (ROOT / "docs" / "own_env.md").read_text()
    return page.split("# Your own environment\n", 1)[1].split("\n## ", 1)[0]


@pytest.fixture
def hover_rocket(monkeypatch):
    """The example env, found as ``--env`` finds it: by its module, from the repository root."""
    monkeypatch.chdir(ROOT)
    return envs.make(ENV_ID)


def test_the_readme_block_is_the_example_file():
    code = re.findall(r"```python\n(.*?)```", _section(), flags=re.S)[0]
    assert code == (ROOT / "examples" / "hover_rocket.py").read_text()


def test_free_fall_and_hovering_are_exact(hover_rocket):
    """Without drag, thrust 0 is free fall (a quadratic in t, which RK4 integrates exactly) and
    action 0 hovers at constant velocity; the limit truncates, the ground terminates."""
    env = hover_rocket
    params = env.default_params.replace(drag=0.0, ceiling=1e9)
    state, ts = env.reset(jax.random.key(0), params)
    h0, v0 = float(state.height), float(state.velocity)
    step = jax.jit(env.step)
    times = np.arange(1, 11) * params.dt
    for t, expected in zip(times, h0 + v0 * times - params.gravity * times**2 / 2, strict=True):
        state, ts = step(jax.random.key(1), state, jnp.array([-1.0]), params)
        assert float(state.height) == pytest.approx(expected, abs=1e-5), t
    hovering = state
    for _ in range(5):
        hovering, _ = step(jax.random.key(1), hovering, jnp.array([0.0]), params)
    assert float(hovering.velocity) == pytest.approx(float(state.velocity), abs=1e-5)
    while not (ts.terminated or ts.truncated):
        state, ts = step(jax.random.key(1), state, jnp.array([-1.0]), params)
    assert ts.terminated and not ts.truncated and float(ts.reward) < -params.crash_penalty + 1


def test_params_vmap_and_the_time_limit(hover_rocket):
    env = hover_rocket
    gravities = jnp.array([5.0, 9.81, 20.0])
    params = jax.vmap(lambda g: env.default_params.replace(gravity=g, drag=0.0))(gravities)
    keys = jax.random.split(jax.random.key(0), 3)
    state, _ = jax.vmap(env.reset)(keys, params)
    stepped, _ = jax.vmap(env.step)(keys, state, jnp.zeros((3, 1)), params)
    # action 0 is 9.81 of thrust: a lighter gravity pushes up, a heavier one pulls down
    change = np.asarray(stepped.velocity - state.velocity)
    np.testing.assert_allclose(change, (9.81 - gravities) * 0.02, atol=1e-5)
    steady = env.default_params.replace(drag=0.0)
    state, _ = env.reset(jax.random.key(0), steady)
    state = state.replace(height=jnp.float32(1.0), velocity=jnp.float32(0.0))
    run = jax.jit(
        lambda s: jax.lax.scan(lambda s, _: env.step(keys[0], s, jnp.zeros(1)), s, None, 200)
    )
    _, ts = run(state)
    assert ts.truncated[-1] and not ts.truncated[:-1].any() and not ts.terminated.any()


def test_gymnasium_make_runs_it_after_registering_with_gymnasium(hover_rocket):
    """Its plain id joins gymnasium's registry; the ``MODULE:ID`` alias is ours only."""
    import gymnasium

    from rl_jax.envs.adapters.gym_adapter import register_with_gymnasium

    register_with_gymnasium()
    assert "examples/HoverRocket-v0" in gymnasium.registry and ENV_ID not in gymnasium.registry
    env = gymnasium.make("examples/HoverRocket-v0")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2,) and env.spec.max_episode_steps == 200


def test_the_readme_command_trains_and_resumes_in_a_fresh_process(tmp_path):
    """The page's command with a budget of 200 steps, in a fresh process from the repository
    root (the module is found in the current directory), then --resume in another one."""
    command = re.findall(r"```bash\n(.*?)```", _section(), flags=re.S)[0].replace("\\\n", " ")
    argv = shlex.split(command)
    assert argv[:2] == ["python", "experiments/train.py"] and ENV_ID in argv
    out = tmp_path / "run"
    environment = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if (path := without_root()) is not None:
        environment["PYTHONPATH"] = path
    for flags in (
        [*argv[2:], *TINY_FLAGS, "--total-steps=200", f"--out={out}"],
        ["--resume", str(out), "--env", ENV_ID, "--total-steps=400"],  # named again
    ):
        done = subprocess.run(
            [sys.executable, "experiments/train.py", *flags],
            cwd=ROOT,
            env=environment,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert done.returncode == 0, done.stderr[-2000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert {row["step"] for row in rows} == {100, 200, 300, 400}
    assert all(np.isfinite(row["eval_return"]) for row in rows)
    assert json.loads((out / "config.json").read_text())["identity"]["env_id"] == ENV_ID
