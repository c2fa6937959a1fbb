"""What touches disk, terminal and processes: the command line, the runner, checkpoints, the run
directory, metrics, plots, progress, policies loaded from runs and rendering."""
