"""An experiment script's defaults, declared once: ``Script(td3, env_id, seeds=...)``, and its
``main(__doc__)`` runs ``rl_jax.run.cli.main`` with them. The settings themselves are the
learner's recipes for the env (``--recipe NAME``; ``rl_jax.training.recipes``)."""

from __future__ import annotations

import dataclasses
import sys
from typing import NoReturn

from rl_jax.run import cli
from rl_jax.training.algorithm import Algorithm


@dataclasses.dataclass(frozen=True)
class Script:
    """An experiment script's learner, env, seeds and budget, run by ``main``::

        SCRIPT = Script(td3, "rl_jax/Pendulum-v1", seeds=5, total_steps=20_000)
        if __name__ == "__main__":
            SCRIPT.main(__doc__)

    Another script can derive its own with ``dataclasses.replace``.
    """

    algorithm: Algorithm
    env_id: str
    seeds: int = 1
    total_steps: int = 100_000

    def main(self, description: str | None, argv: list[str] | None = None) -> NoReturn:
        """Run the script's command line (``argv`` defaults to ``sys.argv[1:]``) with its
        learner, env and defaults; exits with the run's status.
        """
        cli.main(
            self.algorithm,
            self.env_id,
            description,
            seeds=self.seeds,
            total_steps=self.total_steps,
            argv=list(sys.argv[1:] if argv is None else argv),
        )
