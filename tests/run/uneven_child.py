"""A child process for tests/run/test_uneven_devices.py: runs of 5 seeds on DEVICES CPU devices.

    python uneven_child.py DEVICES JOBS_JSON

JOBS_JSON is a list of ``{"out", "total", "resume", "learner"}`` and optionally ``"layout"``
(learner "fake", "td3", a tiny TD3 on the pendulum, or "sac", a tiny SAC on half cheetah; layout
"auto", "pad" or "split"); the last line printed is a JSON list, per job, of ``[devices used,
padded seeds]``. With ``COORDINATOR``, ``NUM_PROCESSES`` and ``PROCESS_ID`` in the environment the
process joins a ``jax.distributed`` run first.
"""

import dataclasses
import json
import os
import sys
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parents[1])]  # tests/: fake_algorithm

from rl_jax.training.jax_setup import configure  # noqa: E402

configure(cpu_devices=int(sys.argv[1]))  # before JAX starts

import jax  # noqa: E402

if os.environ.get("COORDINATOR"):
    jax.distributed.initialize(
        coordinator_address=os.environ["COORDINATOR"],
        num_processes=int(os.environ["NUM_PROCESSES"]),
        process_id=int(os.environ["PROCESS_ID"]),
    )

from uneven_specs import spec_for  # noqa: E402

from rl_jax.run.plan import program_for  # noqa: E402
from rl_jax.run.runner import run  # noqa: E402

layouts = []
for job in json.loads(sys.argv[2]):
    spec = spec_for(job["learner"], Path(job["out"]), job["total"], job["resume"])
    spec = dataclasses.replace(spec, layout=job.get("layout", "auto"))
    layout = program_for(spec).layout
    layouts.append([layout.devices, layout.padded_seeds])
    run(spec, notify=lambda message: None)
print(json.dumps(layouts))
