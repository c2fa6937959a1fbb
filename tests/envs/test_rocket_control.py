"""The rocket's analytic controllers against control theory's closed forms, and the comparison
table and plot that put controllers side by side (``envs.classic.rocket_comparison``).

Facts asserted: the time-optimal feedback from (1, 0) is at rest by t* = 2 s (step 200) and stays
there; t* = v + 2 sqrt(x + v^2/2) above the switching curve (mirrored below) bounds every start;
the LQR gains solve the Riccati equation; the default LQR law settles from (1, 0) at step 319.
"""

import math

import imageio.v3 as iio
import numpy as np
import pytest
import scipy.linalg

from rl_jax.envs.classic import rocket_comparison, rocket_control
from rl_jax.envs.classic.rocket import Rocket, RocketSettle, reward_and_termination

SETTLE = "rl_jax/RocketSettle-v0"
DT = rocket_control.DT
A = np.array([[0.0, 1.0], [0.0, 0.0]])
B = np.array([[0.0], [1.0]])


# ---- time-optimal -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bang_bang():
    return rocket_control.simulate(rocket_control.TimeOptimal(), (1.0, 0.0), 500, SETTLE)


def test_bang_bang_from_one_zero_is_at_rest_at_step_200_and_stays(bang_bang):
    summary = rocket_control.summarize(bang_bang)
    assert 198 <= summary.settle_step <= 202, summary
    assert summary.first_entry_step == summary.settle_step  # it never leaves again
    assert summary.kept and summary.episode_end == "time limit"
    assert summary.settle_time == pytest.approx(2.0, abs=0.02)
    # At rest to rounding within two steps of t*, and held there to the end.
    at_rest = rocket_control.settle_step(bang_bang.positions, bang_bang.velocities, 1e-6)
    assert 200 <= at_rest <= 202
    assert np.max(np.abs(bang_bang.positions[at_rest:])) < 1e-6
    assert np.max(np.abs(bang_bang.velocities[at_rest:])) < 1e-6


def test_bang_bang_thrust_switches_once_at_one_second(bang_bang):
    thrusts = bang_bang.thrusts
    np.testing.assert_array_equal(thrusts[:100], -1.0)  # full thrust back until t = 1 s
    np.testing.assert_allclose(thrusts[101:198], 1.0, atol=1e-4)  # then full thrust forward
    # The velocity peaks at -1 at the switch, on the switching curve x = v^2 / 2 = 0.5.
    assert bang_bang.velocities[100] == pytest.approx(-1.0, abs=1e-5)
    assert bang_bang.positions[100] == pytest.approx(0.5, abs=1e-5)


def test_the_textbook_law_sampled_every_step_does_not_settle():
    """Why ``TimeOptimal`` lands on the curve and holds with deadbeat: ``-sign(s)`` alone
    switches late and chatters in and out of the box (the module docstring's numbers)."""

    def textbook(obs):
        switching = rocket_control.switching_function(obs[0], obs[1])
        return -np.sign(switching if switching != 0 else obs[1]).reshape(1)

    trajectory = rocket_control.simulate(textbook, (1.0, 0.0), 500, SETTLE)
    summary = rocket_control.summarize(trajectory)
    assert summary.first_entry_step > 220, summary
    assert summary.settle_step is None or summary.settle_step > 450, summary


def test_time_optimal_arrival_time_closed_form():
    arrival = rocket_control.time_optimal_arrival_time
    assert arrival(1.0, 0.0) == pytest.approx(2.0)
    assert arrival(-1.0, 0.0) == pytest.approx(2.0)
    assert arrival(0.0, 1.0) == pytest.approx(1 + math.sqrt(2))  # brake, then come back
    assert arrival(0.5, -1.0) == pytest.approx(1.0)  # on the curve: just brake, t* = |v|
    assert arrival(-0.5, 1.0) == pytest.approx(1.0)
    assert arrival(0.0, 0.0) == 0.0
    # Continuous across the switching curve, from either side.
    for v in (-1.3, -0.4, 0.4, 1.3):
        on_curve = -v * abs(v) / 2
        assert arrival(on_curve + 1e-9, v) == pytest.approx(abs(v), abs=1e-4)
        assert arrival(on_curve - 1e-9, v) == pytest.approx(abs(v), abs=1e-4)


@pytest.mark.parametrize(
    "start", [(0.0, 1.0), (-1.0, 0.0), (0.3, 0.7), (-0.5, 0.5), (0.7, -1.0), (-0.25, -0.3)]
)
def test_time_optimal_feedback_arrives_within_two_steps_of_the_bound(start):
    trajectory = rocket_control.simulate(rocket_control.TimeOptimal(), start, 400, SETTLE)
    bound = math.ceil(rocket_control.time_optimal_arrival_time(*start) / DT - 1e-9)
    at_rest = rocket_control.settle_step(trajectory.positions, trajectory.velocities, 1e-6)
    # No law with |u| <= 1 arrives before t*; this one is at most two steps late.
    assert bound <= at_rest <= bound + 2, (start, bound, at_rest)
    assert np.max(np.abs(trajectory.thrusts)) <= 1.0


def test_time_optimal_thrust_far_from_the_curve_is_bang_bang_and_batches():
    controller = rocket_control.TimeOptimal()
    obs = np.array([[1.0, 0.0], [-1.0, 0.0], [0.5, -1.2], [-0.3, 1.0], [0.2, 0.5]], np.float32)
    switching = rocket_control.switching_function(obs[:, 0], obs[:, 1])
    actions = controller(obs)
    assert actions.shape == (5, 1) and actions.dtype == np.float32
    np.testing.assert_array_equal(actions[:, 0], -np.sign(switching))
    for row, action in zip(obs, actions, strict=True):
        np.testing.assert_array_equal(controller(row), action)


def test_deadbeat_thrusts_stop_the_rocket_in_two_steps():
    rng = np.random.default_rng(0)
    for x, v in rng.uniform(-1e-3, 1e-3, (5, 2)):
        first, second = rocket_control.deadbeat_thrusts(x, v, DT)
        for thrust in (first, second):  # the exact held-thrust motion of one step
            x, v = x + v * DT + thrust * DT**2 / 2, v + thrust * DT
        assert abs(x) < 1e-15 and abs(v) < 1e-15


# ---- LQR ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("q1, q2, r", [(1.0, 0.25, 1 / 64), (1.0, 0.0, 1.0), (3.0, 2.0, 0.5)])
def test_lqr_gains_solve_the_riccati_equation(q1, q2, r):
    solution = rocket_control.riccati_solution(q1, q2, r)
    weights = np.diag([q1, q2])
    residual = A.T @ solution + solution @ A - solution @ B @ B.T @ solution / r + weights
    np.testing.assert_allclose(residual, 0.0, atol=1e-12)
    np.testing.assert_allclose(solution, scipy.linalg.solve_continuous_are(A, B, weights, [[r]]))
    gains = rocket_control.lqr_gains(q1, q2, r)
    expected = (math.sqrt(q1 / r), math.sqrt(q2 / r + 2 * math.sqrt(q1 / r)))
    np.testing.assert_allclose(gains, expected, rtol=1e-12)
    closed_loop = A - B @ np.array([gains])
    assert np.all(np.linalg.eigvals(closed_loop).real < 0)


def test_default_lqr_is_critically_damped_with_gains_8_and_4_sqrt2():
    law = rocket_control.lqr()
    assert law.position_gain == pytest.approx(8.0)
    assert law.velocity_gain == pytest.approx(4 * math.sqrt(2))
    poles = np.linalg.eigvals(A - B @ np.array([[law.position_gain, law.velocity_gain]]))
    np.testing.assert_allclose(poles, -2 * math.sqrt(2), atol=1e-6)  # a double real pole


def test_lqr_settles_from_one_zero_without_overshoot():
    trajectory = rocket_control.simulate(rocket_control.lqr(), (1.0, 0.0), 500, SETTLE)
    summary = rocket_control.summarize(trajectory)
    assert 317 <= summary.settle_step <= 321, summary
    assert summary.first_entry_step == summary.settle_step and summary.kept
    assert trajectory.positions.min() > -rocket_control.TOLERANCE
    assert trajectory.thrusts[0] == -1.0  # it asks for -8: saturated at first, as bang-bang
    pd = rocket_control.pd(8.0, 4 * math.sqrt(2))
    np.testing.assert_allclose(pd(np.array([0.1, -0.05])), rocket_control.lqr()([0.1, -0.05]))


# ---- settle_step, summarize and simulate ------------------------------------------------------


def test_settle_step_on_hand_made_sequences():
    settle, tolerance = rocket_control.settle_step, 0.01
    zeros = np.zeros(6)
    assert settle(zeros, zeros, tolerance) == 0
    assert settle([1, 0.5, 0.02, 0.01, 0.0, -0.01], zeros, tolerance) == 3  # closed box
    assert settle([1, 0.0, 0.5, 0.0, 0.0, 0.0], zeros, tolerance) == 3  # in, out, back in
    assert settle([1, 0.0, 0.0, 0.0, 0.0, 0.5], zeros, tolerance) is None  # left at the end
    assert settle(zeros, [0, 0, 0.02, 0, 0, 0], tolerance) == 3  # v counts as much as x
    assert settle(zeros, [0, 0, 0, 0, 0, -0.0101], tolerance) is None
    assert rocket_control.first_entry_step([1, 0.0, 0.5, 0.0], [0, 0, 0, 0], tolerance) == 1
    assert rocket_control.first_entry_step([1, 1], [0, 0], tolerance) is None


def _trajectory(positions, rewards, terminated, goal_tolerance=1e-8):
    positions = np.asarray(positions, np.float64)
    return rocket_control.Trajectory(
        positions=positions,
        velocities=np.zeros_like(positions),
        thrusts=np.zeros(len(rewards)),
        rewards=np.asarray(rewards, np.float64),
        terminated=np.asarray(terminated, bool),
        dt=DT,
        env_id="test",
        goal_tolerance=goal_tolerance,
    )


def test_summary_return_stops_at_the_envs_own_episode_end():
    goal = _trajectory([1, 0.5, 0, 0, 0], [1, 501, 501, 501], [False, True, True, True])
    summary = rocket_control.summarize(goal)
    assert summary.episode_return == 502 and summary.episode_end == "goal at step 2"
    assert summary.settle_step == 2 and summary.kept and summary.final_position == 0
    crash = _trajectory([1, 2.5, 3, 4], [1, -499, -498], [False, True, True])
    summary = rocket_control.summarize(crash)
    assert summary.episode_return == -498 and summary.episode_end == "crashed at step 2"
    assert summary.settle_step is None and summary.first_entry_step is None
    assert not summary.kept and summary.settle_time is None
    plain = rocket_control.summarize(_trajectory([1, 0.5, 0.2], [1, 2], [False, False]))
    assert plain.episode_return == 3 and plain.episode_end == "time limit" and plain.steps == 2


def test_simulate_goes_through_the_env_and_past_its_termination():
    """Constant thrust +1 from (1, 0): x = 1 + t^2/2 crosses the bound 2 at t = sqrt 2."""
    env = Rocket()
    trajectory = rocket_control.simulate(lambda obs: np.ones(1), (1.0, 0.0), 200, env)
    times = trajectory.times
    np.testing.assert_allclose(trajectory.positions, 1 + times**2 / 2, rtol=1e-5)
    np.testing.assert_allclose(trajectory.velocities, times, atol=1e-5)
    crash = math.ceil(math.sqrt(2) / DT)
    assert trajectory.terminated.sum() == 200 - crash + 1  # every step past the bound
    assert rocket_control.summarize(trajectory).episode_end == f"crashed at step {crash}"
    expected, _ = reward_and_termination(
        trajectory.positions[1:].astype(np.float32),
        trajectory.velocities[1:].astype(np.float32),
        env.default_params,
    )
    np.testing.assert_allclose(trajectory.rewards, expected, rtol=1e-6, atol=1e-5)


def test_bang_bang_reaches_even_the_faithful_goal_and_the_rollout_goes_on():
    faithful = rocket_control.simulate(rocket_control.TimeOptimal(), env="rl_jax/Rocket-v0")
    summary = rocket_control.summarize(faithful)
    end = int(summary.episode_end.removeprefix("goal at step "))
    assert 200 <= end <= 202 and faithful.positions.shape == (501,)
    assert summary.episode_return == pytest.approx(faithful.rewards[:end].sum())
    assert summary.kept and summary.final_position == pytest.approx(0.0, abs=1e-8)


def test_settle_variant_keeps_the_rocket_dynamics():
    """The report rolls runs of either variant in one env: they must share their dynamics."""
    controller = rocket_control.TimeOptimal()
    faithful = rocket_control.simulate(controller, (0.3, 0.7), 300, Rocket())
    settle = rocket_control.simulate(controller, (0.3, 0.7), 300, RocketSettle())
    np.testing.assert_array_equal(faithful.positions, settle.positions)
    np.testing.assert_array_equal(faithful.velocities, settle.velocities)


# ---- the comparison's table and plot ------------------------------------------------------------


def test_comparison_of_the_analytic_laws_writes_their_table_and_plot(tmp_path):
    settings = rocket_comparison.Settings("rl_jax/Rocket-v0", (1.0, 0.0), 500, 0.01, DT)
    entries = rocket_comparison.analytic_entries(settings)
    assert [entry.learned for entry in entries] == [False, False]
    plot_path, table_path = rocket_comparison.write_report(entries, settings, tmp_path / "out")
    table = table_path.read_text()
    assert table.startswith(rocket_comparison.headline(settings))
    assert "t* = 2.00 s (step 200)" in table and "kept to step 500?" in table
    assert "| bang-bang (time-optimal) | - | - | 200 (2.00 s) | yes |" in table
    assert "| LQR, K = (8, 5.66) | - | - | 319 (3.19 s) | yes |" in table
    assert iio.imread(plot_path).shape[:2] == (750, 1200)
