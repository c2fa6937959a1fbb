"""Bridges to other env libraries: our envs as gymnasium envs, gymnasium envs as ours (stepped on
the host, with the ``gymnasium:ID`` and ``MODULE:ID`` ids), and brax."""
