"""A stop signal that comes once a sweep's shape is trained (its last checkpoint, its plots, the
next shape's start) stops the sweep before its next shape, rather than being forgotten when the
shape's run ends: the shapes trained are kept, ``--resume`` trains the rest, and SIGUSR1 requeues
the job once. Shapes run in turn (``sweep.run_sweep``) and each process's own (``run_own``)."""

import os
import signal

import fake_algorithm as fake
import pytest
from run_helpers import leaves_bytes

from rl_jax.run import distributed, learners, runner, sweep
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.sweep_shapes import run_own

# Two shapes (the envs per seed), each 2 seeds x 2 chunks.
ARGV = ["--algo", "fake", "--env", fake.ENV_ID, "--seeds", "2", "--log-interval", "0"]
ARGV += ["--total-steps", "40", "--grid", "num_envs=4,2", "--iterations-per-chunk", "5"]
SHAPES = ("num_envs=4", "num_envs=2")


def signal_once_trained(monkeypatch, where: str, signum: int) -> None:
    """Send ``signum`` once, from the run's own thread, when the first shape's run has saved its
    last checkpoint (``where="save"``: the run's handler catches it) or is writing its plots
    (``"finish"``: the run's handler is gone by then, the sweep's catches it)."""
    sent = []

    def send() -> None:
        if not sent:
            sent.append(signum)
            os.kill(os.getpid(), signum)

    if where == "save":
        save = runner.Session.save

        def save_then_signal(session, state, hparams, chunk):
            save(session, state, hparams, chunk)
            if session.step >= session.plan.final_steps:
                send()

        monkeypatch.setattr(runner.Session, "save", save_then_signal)
    else:
        finish = runner._finish

        def finish_after_signal(*args, **kwargs):
            send()
            return finish(*args, **kwargs)

        monkeypatch.setattr(runner, "_finish", finish_after_signal)


def latest_step(run_dir) -> int | None:
    if not (run_dir / "checkpoints").is_dir():
        return None
    with Checkpointer(run_dir / "checkpoints", read_only=True) as checkpointer:
        return checkpointer.latest_step()


@pytest.fixture(autouse=True)
def outer_handlers():
    """Handlers of the test process's own for the signals sent: a signal that no stop of the
    sweep's catches is recorded here (and fails the test) instead of ending the process."""
    missed = []
    previous = {
        signum: signal.signal(signum, lambda got, frame: missed.append(got))
        for signum in (signal.SIGTERM, signal.SIGUSR1)
    }
    yield missed
    for signum, handler in previous.items():
        signal.signal(signum, handler)
    assert missed == [], "a signal reached the process's own handler"


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """The sweep never stopped: the reference for the resumed ones."""
    learners.register_algorithm("fake", "fake_algorithm")
    out = tmp_path_factory.mktemp("whole") / "sweep"
    assert sweep.run_sweep([*ARGV, "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("where", ["save", "finish"])
def test_a_signal_once_a_shape_is_trained_stops_the_sweep_before_the_next(
    whole, where, tmp_path, monkeypatch, capsys
):
    out = tmp_path / "sweep"
    requeued = []
    monkeypatch.setattr(distributed, "slurm_requeue", lambda notify: requeued.append(1))
    handler_before = signal.getsignal(signal.SIGTERM)
    signal_once_trained(monkeypatch, where, signal.SIGTERM)
    assert sweep.run_sweep([*ARGV, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "SIGTERM: stopping" in printed
    assert "stopped before shape 2/2; the shapes before it are saved." in printed
    assert "resume with: " in printed and f"--resume {out}" in printed
    assert latest_step(out / SHAPES[0]) == 40 and latest_step(out / SHAPES[1]) is None
    assert not (out / "results.txt").exists()  # no ranking of a sweep that did not end
    assert requeued == []  # SIGTERM: no requeue
    assert signal.getsignal(signal.SIGTERM) is handler_before
    monkeypatch.undo()
    learners.register_algorithm("fake", "fake_algorithm")
    assert sweep.run_sweep(["--resume", str(out), "--algo", "fake"]) == 0
    for shape in SHAPES:
        assert latest_step(out / shape) == 40
    assert (out / "results.txt").is_file()
    resumed = runner.run(
        sweep.build_specs(["--resume", str(out), "--algo", "fake"])[0][1],
        notify=lambda message: None,
    )
    reference = runner.run(
        sweep.build_specs(["--resume", str(whole), "--algo", "fake"])[0][1],
        notify=lambda message: None,
    )
    assert leaves_bytes(resumed.state) == leaves_bytes(reference.state)


def test_sigusr1_between_a_process_own_shapes_stops_it_and_requeues_once(tmp_path, monkeypatch):
    learners.register_algorithm("fake", "fake_algorithm")
    specs, labels, _, _ = sweep.build_specs([*ARGV, "--out", str(tmp_path / "sweep")])
    requeued = []
    monkeypatch.setattr(distributed, "slurm_requeue", lambda notify: requeued.append(1))
    signal_once_trained(monkeypatch, "finish", signal.SIGUSR1)
    messages = []
    assert run_own(specs, labels, [0, 0], notify=messages.append) is True
    assert latest_step(specs[0].out) == 40 and latest_step(specs[1].out) is None
    assert requeued == [1]
    assert any(m.startswith("SIGUSR1: stopping before this process's next shape") for m in messages)
    assert f"stopped before {SHAPES[1]}; the shapes before it are saved." in messages
