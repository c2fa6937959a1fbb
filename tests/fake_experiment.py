"""An experiment script over the fake learner, run as a subprocess by the CLI tests.

python tests/fake_experiment.py [flags]          the fake algorithm on its point env
python tests/fake_experiment.py --generic [...]  --algo/--env chosen on the command line
"""

import os
import sys
from pathlib import Path

# Real scripts import rl_jax first, which sets this before jax loads; this one imports the fake
# learner (and so jax) first.
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")

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
