"""An experiment script over the fake learner, run as a subprocess by the CLI tests.

python tests/fake_experiment.py [flags]          the fake algorithm on its point env
python tests/fake_experiment.py --generic [...]  --algo/--env chosen on the command line
"""

import sys
from pathlib import Path

# As real scripts do, rl_jax first: it sets jax's C++ log level before the fake learner loads jax.
import rl_jax  # noqa: E402, F401

sys.path.insert(0, str(Path(__file__).resolve().parent))

import fake_algorithm  # noqa: E402

from rl_jax.run import cli, learners  # noqa: E402

learners.register_algorithm("fake", "fake_algorithm")

if __name__ == "__main__":
    argv = sys.argv[1:]
    generic = "--generic" in argv
    argv = [arg for arg in argv if arg != "--generic"]
    cli.main(
        None if generic else fake_algorithm,
        None if generic else fake_algorithm.ENV_ID,
        __doc__,
        seeds=2,
        total_steps=100,
        argv=argv,
    )
