"""Fixtures of the run tests that several files share, made once per test process."""

import pytest
import tiny_board_run


@pytest.fixture(scope="session")
def trained(tmp_path_factory):
    """A tiny trained AlphaZero run on tic-tac-toe (tests/tiny_board_run.py). Shared by the
    board-game files: a test may resume it (more steps) but must leave it a valid run."""
    return tiny_board_run.train(tmp_path_factory.mktemp("board") / "run")
