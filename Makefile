# rl_jax — every set-up step lives here so that a fresh machine needs only Python 3.11 and pip.
#   make train   install, then train TD3 on half cheetah with 5 seeds
#   make test    install, then run the test suite (what CI runs)
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

# The persistent XLA compilation cache is on by default (a second run of a config skips compiling):
# rl_jax.training.jax_setup keeps it in ~/.cache/rl_jax/jax/<CPU tag>, unless
# JAX_COMPILATION_CACHE_DIR names another directory.
# Headless MuJoCo rendering picks EGL, else OSMesa, when a frame is first drawn
# (envs/mujoco/opengl.py); nothing else needs OpenGL, so MUJOCO_GL is not set here.

.PHONY: install test test-slow lint format bench results train lock system-deps clean help

help:
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed 's/:.*## /\t/' | sort

install: $(STAMP) system-deps ## create .venv and install the locked dependencies (idempotent)

# Re-installs only when the lock or pyproject changed; `pip install -r` of a hashed lock is exact.
$(STAMP): requirements.lock pyproject.toml
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found; install Python 3.11 or run 'make PYTHON=python3 ...'" >&2; exit 1; }
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	$(BIN)/python -m envs.mujoco.mujoco_ffi_build  # the MuJoCo C step op (g++); without it: a callback
	@touch $@

system-deps: ## install the system libraries for headless rendering (EGL), where possible
	@bash scripts/system_deps.sh

test: install ## run the default (fast) test suite
	$(BIN)/python -m pytest -q

test-slow: install ## run the long learning tests only
	$(BIN)/python -m pytest -q -m slow

lint: install ## ruff lint + format check
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: install ## apply ruff formatting and safe fixes
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

bench: install ## run the benchmarks and print the tables (see BENCHMARKS.md)
	$(BIN)/python -m bench

results: install ## regenerate every row of RESULTS.md, one long training run at a time
	$(BIN)/python -m bench.results all

train: install ## train TD3 on half cheetah, 5 seeds in one compiled program
	$(BIN)/python experiments/td3_cheetah.py --seeds 5

lock: ## regenerate requirements.lock from pyproject.toml (needs network)
	@test -x $(BIN)/pip-compile || $(MAKE) install
	$(BIN)/pip-compile --quiet --extra dev --strip-extras --generate-hashes --allow-unsafe \
		--no-emit-index-url --no-emit-find-links --upgrade -o requirements.lock pyproject.toml

clean: ## remove the venv and caches (runs/ is kept)
	rm -rf $(VENV) .pytest_cache .ruff_cache
