"""Sweep a grid of hyperparameters x seeds as one compiled program, sharded over all devices.

  python experiments/sweep.py --algo td3 --env rl_jax/Pendulum-v1 \
      --grid lr=1e-4,3e-4,1e-3 --grid tau=0.005,0.02 --seeds 5

Grid names are hyperparameter or config fields (``--help`` with --algo/--env lists them) or the
short names lr (actor and critic learning rates together), width (both networks' hidden widths,
e.g. width=64x64,256x256), batch (batch_size) and buffer (buffer_size). Hyperparameters (learning
rates, tau, gamma, noise) are vmapped: every value x every seed is one compiled program, split
over the local devices (both CPU cores here). Config fields change shapes (width, batch, buffer
size): each shape compiles once and runs its whole hyperparameter grid in its own program.

OUT (default runs/<env>__<algo>-sweep__<time>/) holds one run directory per shape (config.json,
metrics.jsonl, checkpoints, ... as every experiment script), plus curves.png with one curve per
config and results.txt ranking all configs by final eval return with 95% bootstrap CIs.
--resume OUT continues every shape from its latest checkpoint.

Several hosts (or processes) through jax.distributed: under SLURM or Open MPI add --distributed
(srun/mpirun start the processes); elsewhere start the same command on every process, adding
--coordinator HOST:PORT (process 0's address, any free port), --num-processes N and
--process-id I (0 .. N-1). The grid x seeds is then sharded over the devices of all processes;
each process computes its share and process 0 alone writes OUT and prints the progress. The
checkpoints are the same as on one process: to resume, start the same processes again with
--resume OUT in place of the grid flags (Ctrl-C, SIGTERM or SIGUSR1 to any process stops them
all after the chunk, with a checkpoint). On one machine, 2 processes:

  python -m rl_jax.run.launch --local 2 experiments/sweep.py --algo td3 \
      --env rl_jax/Pendulum-v1 --grid lr=1e-4,1e-3 --seeds 2 --out runs/distributed

With several processes, the shapes of a grid are shared out instead, where that is faster than
running each over all of them in turn (rl_jax/run/sweep_shapes.py): each process compiles and
trains only its own shapes and writes their run directories, so OUT must be a directory that
every process sees (a shared file system on a cluster). docs/cluster.md has sbatch templates,
requeue and the launcher's SLURM mode.
"""

from rl_jax.run import sweep

if __name__ == "__main__":
    sweep.main(__doc__)
