"""SBX's SAC (``sbx-rl``) timed on a gymnasium env: the peer ``bench_peers_sac`` sets beside our
SAC. The same timing as ``bench/sbx_td3.py`` (whose ``main`` this runs), with ``sbx.SAC``: the
networks and batch given for actor and twin critics, one update per env step, the temperature
learned towards an entropy of -|A|. Runs in the peers' venv; imports nothing of rl_jax.

    .venv-peers/bin/python bench/sbx_sac.py --env-id HalfCheetah-v5 --hidden 256,256 \
        --batch-size 256 --updates 2000
"""

from __future__ import annotations

# Run as a script, this file's folder is on sys.path: sbx_td3 is its neighbour, not a package.
from sbx_td3 import main

if __name__ == "__main__":
    main(algo="SAC", doc=__doc__)
