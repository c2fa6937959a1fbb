"""The settle goal of the rocket's slow tests, shared by TD3's and DQN's."""

from __future__ import annotations

from pathlib import Path

from experiments import rocket_report


def assert_every_latest_policy_settles(run_dir: Path, seeds: int) -> None:
    """Every seed's latest policy of ``run_dir``, rolled from (1, 0) by ``rocket_report``,
    enters |x|, |v| <= 0.01 and stays inside to the episode's last step."""
    entries, _ = rocket_report.compare([run_dir], which="latest")
    learned = [entry for entry in entries if entry.learned]
    for entry in learned:
        print(f"seed {entry.seed}: settled at step {entry.summary.settle_step}")
    assert len(learned) == seeds
    assert all(entry.summary.kept for entry in learned), [e.summary.kept for e in learned]
