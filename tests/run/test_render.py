"""Rendering a run's policy: the GIF holds the env's frames of the policy's own rollout; the CLI
reports problems (bad seed, no run, no OpenGL backend) in one line."""

import ctypes.util
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import fake_algorithm as fake
import imageio.v2 as imageio
import jax
import numpy as np
import pytest
from child_env import python_path
from run_helpers import fake_run

from rl_jax.run import render
from rl_jax.run.metrics import read_rows
from rl_jax.run.policy import LoadedPolicy

ROOT = Path(__file__).resolve().parents[2]
# A user's shell (see test_cli.py): without the TF_CPP_MIN_LOG_LEVEL=1 that importing jax set
# here, whose warnings (a cached program's version note) would add lines to a child's stderr.
ENV = {
    **{key: value for key, value in os.environ.items() if key != "TF_CPP_MIN_LOG_LEVEL"},
    "PYTHONPATH": python_path(ROOT, ROOT / "tests"),
}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    return fake_run(tmp_path_factory.mktemp("render") / "run", total_steps=60)


def without_repeats(frames):
    """GIF encoders merge a frame equal to the previous one into it."""
    kept = [frames[0]]
    for frame in frames[1:]:
        if not np.array_equal(frame, kept[-1]):
            kept.append(frame)
    return kept


def test_gif_holds_the_frames_of_the_policy_rollout(run_dir, tmp_path):
    path = render.write_gif(run_dir, seed=1, episodes=2, out=tmp_path / "p.gif")
    loaded = LoadedPolicy(run_dir, seed=1)
    assert loaded.seed == 1 and loaded.which == "best"
    env = loaded.env()
    episodes = render.rollout(env, fake.policy(loaded.state, loaded.config), jax.random.key(1), 2)
    assert [len(e["states"]) for e in episodes] == [21, 21]  # reset + 20 steps to truncation
    expected = [f for e in episodes for f in render.episode_frames(env, e["states"])]
    assert expected[0].shape == (32, 64, 3)
    written = [frame[..., :3] for frame in imageio.mimread(path)]
    assert len(written) == len(without_repeats(expected))
    for got, want in zip(written, without_repeats(expected), strict=True):
        np.testing.assert_array_equal(got, want)


def test_default_seed_is_the_best_eval_and_its_best_policy(run_dir):
    rows = read_rows(run_dir / "metrics.jsonl")
    final = [row for row in rows if row["step"] == 60]
    best_final = max(final, key=lambda row: row["eval_return"])["seed"]
    assert LoadedPolicy(run_dir, which="latest").seed == best_final
    best = max(rows, key=lambda row: (row["eval_return"], -row["step"]))
    loaded = LoadedPolicy(run_dir)
    assert (loaded.which, loaded.seed, loaded.step) == ("best", best["seed"], best["step"])
    assert loaded.eval_return == pytest.approx(best["eval_return"], rel=1e-6)


def test_episode_return_matches_a_direct_rollout(run_dir):
    loaded = LoadedPolicy(run_dir, seed=0)
    act = loaded.algorithm.policy(loaded.state, loaded.config)
    (episode,) = render.rollout(loaded.env(), act, jax.random.key(3), 1)
    positions = np.array([float(s.position) for s in episode["states"][1:]])
    assert episode["return"] == pytest.approx(-np.sum(positions**2), rel=1e-5)


def test_render_command_line(run_dir, tmp_path, capsys):
    command = [
        sys.executable,
        "-m",
        "rl_jax.run.render",
        str(run_dir),
        "--seed",
        "0",
        "--out",
        str(tmp_path / "cli.gif"),
        "--algo",  # a learner not built in is named, never imported from the run's record
        "fake_algorithm",
    ]
    # In a fresh process, which has not imported the learner: a rendering.
    done = subprocess.run(command, env=ENV, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "rendered seed 0 (config 0) at step " in done.stdout
    assert "its best policy" in done.stdout
    assert (tmp_path / "cli.gif").stat().st_size > 100
    # The rest through the command's main, in this process: an error that gets as far as
    # opening the run, the latest policy, and argparse's and a missing run's errors.
    assert render.main([*command[3:4], "--algo", "fake_algorithm", "--seed", "9"]) != 0
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert (
        lines[0].startswith("error: ") and "--seed 9 is not in this run (seeds [0, 1])" in lines[0]
    )
    assert render.main([*command[3:], "--latest"]) == 0
    assert "rendered seed 0 (config 0) at step 60, its latest policy" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exited:  # argparse's own error
        render.main([*command[3:4], "--algo", "fake_algorithm", "--episodes", "0"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert exited.value.code != 0 and len(lines) == 1, lines
    assert lines[0].startswith("error: ") and "argument --episodes: must be >= 1" in lines[0]
    assert render.main([str(tmp_path / "none")]) != 0
    assert capsys.readouterr().err.strip().splitlines() == [
        f"error: no run directory at {tmp_path / 'none'}"
    ]


MUJOCO_RENDER = textwrap.dedent(
    """
    import numpy as np
    from rl_jax.errors import guard
    from rl_jax.run import render

    XML = '<mujoco><worldbody><light pos="0 0 3"/><body name="ball" mocap="true">'
    XML += '<geom type="sphere" size="0.2" rgba="1 0 0 1"/></body></worldbody></mujoco>'

    class Ball:
        default_params = None

        def render_episode(self, states, params):
            import mujoco  # as a MuJoCo env would: loading mujoco picks the GL backend

            model = mujoco.MjModel.from_xml_string(XML)
            data = mujoco.MjData(model)
            with mujoco.Renderer(model, 48, 64) as renderer:
                frames = []
                for x in states:
                    data.mocap_pos[0] = [x, 0, 0]
                    mujoco.mj_forward(model, data)
                    renderer.update_scene(data)
                    frames.append(renderer.render())
            return frames

    def main():
        frames = render.episode_frames(Ball(), [-0.5, 0.0, 0.5])
        print(len(frames), frames[0].shape, int(np.argmax(frames[0][24].sum(-1) > 0)))
        return 0

    raise SystemExit(guard(main))
    """
)


def _render_mujoco(gl: str) -> subprocess.CompletedProcess:
    """MUJOCO_RENDER in a fresh process with MuJoCo's OpenGL backend ``gl``."""
    return subprocess.run(
        [sys.executable, "-c", MUJOCO_RENDER],
        capture_output=True,
        text=True,
        env={**ENV, "MUJOCO_GL": gl},
        timeout=300,
    )


def test_mujoco_frames_through_the_episode_hook_with_egl():
    done = _render_mujoco("egl")
    if "no OpenGL backend" in done.stderr:
        pytest.skip("EGL is not installed here")
    assert done.returncode == 0, done.stderr
    count, shape, _ = done.stdout.split(" ", 2)
    assert count == "3" and shape.startswith("(48,")


@pytest.mark.skipif(bool(ctypes.util.find_library("OSMesa")), reason="OSMesa is installed")
def test_missing_opengl_backend_is_one_line_saying_what_to_install():
    done = _render_mujoco("osmesa")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert lines[0].startswith("error: no OpenGL backend for headless rendering: install EGL")
    assert "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri" in lines[0]


def test_episode_plot_hook_and_frame_rate(run_dir, tmp_path, monkeypatch):
    seen = {}

    def episode_plot(env, states, params, path):
        seen["positions"] = [float(state.position) for state in states]
        path.write_bytes(b"plot")

    monkeypatch.setattr(fake.PointEnv, "episode_plot", episode_plot, raising=False)
    path = render.write_gif(run_dir, seed=0, out=tmp_path / "policy.gif")
    assert (tmp_path / "policy_episode.png").read_bytes() == b"plot"
    assert len(seen["positions"]) == 21  # the unwrapped env's states, reset included
    monkeypatch.setattr(fake.PointEnv, "render_fps", 200, raising=False)
    render.write_gif(run_dir, seed=0, out=tmp_path / "fast.gif")
    # 200 fps plays in real time as every 4th frame at 50 fps (20 ms per frame).
    with imageio.get_reader(tmp_path / "fast.gif") as reader:
        assert reader.get_meta_data()["duration"] == 20
    assert path.exists()


NO_OPENGL_SCRIPT = textwrap.dedent(
    """
    import jax, numpy as np
    import rl_jax
    from rl_jax import envs
    from rl_jax.envs.mujoco.opengl import OpenGLUnavailableError

    env = envs.make("rl_jax/InvertedPendulum-v5")
    state, step = env.reset(jax.random.key(0))
    state, step = jax.jit(env.step)(jax.random.key(1), state, np.zeros(1, np.float32))
    policy = rl_jax.load_policy(OLD_RUN)
    action = policy(np.zeros(3, np.float32))
    try:
        env.render(state)
    except OpenGLUnavailableError as error:
        print("render:", error)
    print("stepped", bool(np.isfinite(step.reward)), np.shape(action))
    """
)


@pytest.mark.parametrize("gl", ["", "egl"])
def test_no_opengl_library_only_rendering_needs_it(tmp_path, gl):
    """A machine without libEGL/libOSMesa/libGL (a GPU server, a slim container): importing,
    stepping and loading a policy work; rendering says in one line what to install. Empty files
    named like the libraries make every dlopen of them fail, as on such a machine."""
    for name in ("libEGL.so.1", "libEGL.so", "libGL.so.1", "libOSMesa.so.8", "libOSMesa.so"):
        (tmp_path / name).write_bytes(b"")
    env = {**ENV, "LD_LIBRARY_PATH": str(tmp_path), "MUJOCO_GL": gl}
    env.pop("DISPLAY", None)
    old_run = ROOT / "tests" / "data" / "old_run_td3"
    script = f"OLD_RUN = {str(old_run)!r}\n" + NO_OPENGL_SCRIPT
    done = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    # Our two lines, found by their starts: on a GPU host the libraries may print lines of
    # their own to stdout (the H100 run had a third line).
    lines = done.stdout.strip().splitlines()
    render_lines = [line for line in lines if line.startswith("render:")]
    assert [line for line in lines if line.startswith("stepped")] == ["stepped True (1,)"], lines
    assert len(render_lines) == 1, lines
    assert render_lines[0].startswith("render: no OpenGL backend for headless rendering"), lines
    assert "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri" in render_lines[0]
