"""The progress line: rates, ETA and eval over seeds, on a terminal and in a log file."""

import io
import re

import numpy as np
import pytest

from rl_jax.run import progress as progress_module
from rl_jax.run.progress import Progress, eval_summary


class FakeClock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


@pytest.fixture
def clock(monkeypatch):
    fake = FakeClock()
    monkeypatch.setattr(progress_module.time, "perf_counter", fake)
    return fake


def test_eval_summary_gives_mean_and_range_over_seeds():
    assert eval_summary(np.array([[1.0, 2.0, 6.0]])) == "eval 3.0 [1.0, 6.0]"
    assert eval_summary(np.array([[5.0]])) == "eval 5.0"
    assert eval_summary(np.array([np.nan, 4.0, 2.0])) == "eval 3.0 [2.0, 4.0]"
    assert eval_summary(np.array([np.nan])) == "eval n/a"


def test_log_lines_have_rates_eta_and_eval(clock):
    out = io.StringIO()
    bar = Progress(total_steps=10_000, runs=4, file=out, tty=False, log_interval=30)
    bar.start()
    clock.now += 2.0
    bar.update(2_000, 500, np.array([[-10.0, -20.0, -30.0, -40.0]]))
    line = out.getvalue().strip()
    # 2,000 steps x 4 runs in 2 s; 500 updates x 4 runs in 2 s; 8,000 steps left at 1,000/s.
    assert line.startswith("step 2,000/10,000 (20%)")
    assert "4.0k env steps/s" in line and "1.0k updates/s" in line
    assert "eval -25.0 [-40.0, -10.0]" in line
    assert "elapsed 0:00:02, ETA 0:00:08" in line
    assert "\r" not in out.getvalue()


def test_log_lines_are_throttled_but_the_last_is_printed(clock):
    out = io.StringIO()
    bar = Progress(total_steps=300, file=out, tty=False, log_interval=30)
    bar.start()
    for step in (100, 200, 300):
        clock.now += 10.0
        bar.update(step, step, np.zeros((1, 1)))
    lines = out.getvalue().strip().splitlines()
    assert [line.split()[1] for line in lines] == ["100/300", "300/300"]


def test_rates_count_only_this_session_after_a_resume(clock):
    out = io.StringIO()
    bar = Progress(total_steps=2_000, start_steps=1_000, start_updates=250, file=out, tty=False)
    clock.now += 100.0  # compilation: not counted
    bar.start()
    clock.now += 5.0
    bar.update(1_500, 375, np.zeros((1, 1)))
    assert "100 env steps/s" in out.getvalue() and "25 updates/s" in out.getvalue()
    assert "ETA 0:00:05" in out.getvalue()


def test_terminal_bar_shows_status_and_messages(clock):
    out = io.StringIO()
    bar = Progress(total_steps=1_000, file=out, tty=True)
    bar.write("compiled in 3.0 s")
    bar.start()
    clock.now += 1.0
    bar.update(500, 100, np.array([[1.0, 3.0]]))
    bar.write("a message")
    bar.close()
    text = out.getvalue()
    assert "compiled in 3.0 s" in text and "a message" in text
    assert "eval 2.0 [1.0, 3.0]" in text
    assert re.search(r"50%.*500/1.00k \[00:00, ETA .*\], 500 env steps/s", text)
