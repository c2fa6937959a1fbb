# rl_jax — every set-up step lives here so that a fresh machine needs only Python 3.11 and pip.
#   make train   install, then train TD3 on half cheetah with 5 seeds
#   make test    install, then run the test suite (CI runs make lint, make typecheck, make docs,
#                make docs-check, then this)
#   make install GPU=1        also the CUDA 12 build of the pinned jaxlib (requirements-gpu.lock)
#   make test-latest          the default suite against the newest releases, in .venv-latest
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
GPU    ?=
GPU_STAMP := $(VENV)/.installed-gpu
# `make test-latest`: a second venv with the newest releases of our direct dependencies (pip
# resolves them afresh each time), on the newest Python that jax supports here.
# (a pyenv shim may exist without a version behind it: the first that runs wins)
LATEST_PYTHON ?= $(shell for p in python3.12 $$HOME/.pyenv/versions/3.12*/bin/python3.12 python3.11; \
	do $$p --version >/dev/null 2>&1 && { echo $$p; break; }; done)
LATEST_VENV := .venv-latest

# The persistent XLA compilation cache is on by default (a second run of a config skips compiling):
# rl_jax.training.jax_setup keeps it in ~/.cache/rl_jax/jax/<CPU tag>, unless
# JAX_COMPILATION_CACHE_DIR names another directory.
# Headless MuJoCo rendering picks EGL, else OSMesa, when a frame is first drawn
# (envs/mujoco/opengl.py); nothing else needs OpenGL, so MUJOCO_GL is not set here.

.PHONY: install test test-slow test-latest lint typecheck format bench results figures train lock \
	lock-gpu system-deps clean help

help:
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed 's/:.*## /\t/' | sort

install: $(STAMP) $(if $(GPU),$(GPU_STAMP)) system-deps ## create .venv and install the locked dependencies (GPU=1: with CUDA)

# Re-installs only when the lock or pyproject changed; `pip install -r` of a hashed lock is exact.
# --no-compile, then compileall over every core: pip compiles the packages' bytecode one file at a
# time, compileall on all cores at once, beside the build of the MuJoCo C step op.
# requirements-nodeps.lock: gymnax, whose declared gymnasium<1.4 no resolver can meet beside our
# gymnasium 1.4 (pyproject.toml's minatar extra says why it runs there); what it imports is in
# requirements.lock, so it goes in without its declared dependencies, hash-checked all the same.
$(STAMP): requirements.lock requirements-nodeps.lock pyproject.toml
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found; install Python 3.11 or run 'make PYTHON=python3 ...'" >&2; exit 1; }
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-compile -r requirements.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-compile --no-deps \
		-r requirements-nodeps.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	@# the bytecode and the MuJoCo C step op (g++, one core; without it: a callback) side by side
	@$(BIN)/python -m compileall -q -j 0 "$$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')" >/dev/null & \
	$(BIN)/python -m rl_jax.envs.mujoco.mujoco_ffi_build; status=$$?; wait; exit $$status
	@touch $@

# The CUDA 12 plugin of the same jaxlib, with its NVIDIA libraries as wheels (no system CUDA
# needed, only an NVIDIA driver): jax then runs on the GPU and MuJoCo envs default to MJX there.
$(GPU_STAMP): $(STAMP) requirements-gpu.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements-gpu.lock
	@$(BIN)/python -c "import jax; print('jax devices:', jax.devices())"
	@touch $@

system-deps: ## install the system libraries for headless rendering (EGL), where possible
	@bash scripts/system_deps.sh

# Test files are spread over TEST_WORKERS processes (pytest-xdist), each file whole in one of them
# so that its tests share their compiled programs; a cold run is mostly XLA compiling, one core per
# program. TEST_WORKERS=0 runs everything in this process. One OpenBLAS thread per test process
# (tests/conftest.py says why).
TEST_WORKERS ?= 2

test: install ## run the default (fast) test suite
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=20

test-latest: ## the default suite against the newest jax, flax, optax, orbax, mujoco, gymnasium, pgx, mctx (.venv-latest)
	@test -x $(LATEST_VENV)/bin/python || $(LATEST_PYTHON) -m venv $(LATEST_VENV)
	$(LATEST_VENV)/bin/python -m pip install --quiet --disable-pip-version-check --upgrade \
		jax jaxlib flax optax orbax-checkpoint mujoco mujoco-mjx brax "gymnasium[mujoco]" numpy \
		matplotlib tensorboardX tqdm imageio pillow pygame-ce pytest pytest-timeout pytest-xdist scipy setuptools \
		minatar seaborn six pgx mctx
	@# gymnax without its declared gymnasium<1.4, which would pull gymnasium back (see make install)
	$(LATEST_VENV)/bin/python -m pip install --quiet --disable-pip-version-check --upgrade --no-deps gymnax
	$(LATEST_VENV)/bin/python -m pip install --quiet --disable-pip-version-check --no-deps \
		--no-build-isolation -e .
	@$(LATEST_VENV)/bin/python -m pip list 2>/dev/null | grep -iE '^(jax|jaxlib|flax|optax|orbax-checkpoint|mujoco|mujoco-mjx|brax|gymnasium|gymnax|numpy|pgx|mctx) '
	$(LATEST_VENV)/bin/python -m rl_jax.envs.mujoco.mujoco_ffi_build
	OPENBLAS_NUM_THREADS=1 $(LATEST_VENV)/bin/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-slow: install ## run the long learning tests only
	$(BIN)/python -m pytest -q -m slow

lint: install ## ruff lint + format check
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

# mypy over rl_jax/ and rl_jax/envs (settings in pyproject.toml; its cache in .mypy_cache), failing
# when the errors outnumber scripts/typecheck_baseline.txt, and when they fall short of it (then
# `$(BIN)/python scripts/typecheck.py --update` lowers it).
typecheck: install ## mypy against its baseline of known errors, which may only shrink
	$(BIN)/python scripts/typecheck.py

# The documentation site (docs/: MyST pages; conf.py; _ext/ writes the tables of options, recipes
# and envs from the code). Warnings are errors, and so is a local link or image that resolves to
# nothing. Every docs/*.md page joins the site through index.md's glob toctree.
.PHONY: docs
docs: install ## build the documentation site into docs/_build/html (warnings are errors)
	$(BIN)/python -m sphinx -W --keep-going -q -j auto -b html docs docs/_build/html

# The site `make docs` built, read in headless Chromium at 1,280 px (scripts/docs_check.py): no
# broken image, maths typeset offline, no table or element wider than its column, every link and
# anchor inside the site there. scripts/docs_check.sh installs Chromium and its driver if missing.
.PHONY: docs-check
docs-check: install ## check the built site in headless Chromium: images, maths, widths, links
	@bash scripts/docs_check.sh
	$(BIN)/python scripts/docs_check.py docs/_build/html

format: install ## apply ruff formatting and safe fixes
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

bench: install ## run the benchmarks and print the tables (see BENCHMARKS.md)
	$(BIN)/python -m bench

results: install ## regenerate every row of RESULTS.md, one long training run at a time
	$(BIN)/python -m bench.results all

figures: install ## redraw docs/figures/ from the runs named in docs/figures/manifest.toml
	$(BIN)/python -m bench.figures

train: install ## train TD3 on half cheetah, 5 seeds in one compiled program
	$(BIN)/python experiments/td3_cheetah.py --seeds 5

# The lock holds the library and its test, dev, docs, tracking and minatar extras (gymnax itself:
# requirements-nodeps.lock, written by hand: see its header). pip-compile keeps every
# pin in requirements.lock that pyproject.toml still admits (adding, dropping or moving only what
# changed); UPGRADE=1 takes the newest release of everything inside pyproject.toml's ranges instead.
UPGRADE ?=
lock: ## regenerate requirements.lock from pyproject.toml (needs network; UPGRADE=1: newest in range)
	@test -x $(BIN)/pip-compile || $(MAKE) install
	$(BIN)/pip-compile --quiet --extra test --extra dev --extra docs --extra tracking --extra minatar --extra atari \
		--strip-extras \
		--generate-hashes --allow-unsafe --no-emit-index-url --no-emit-find-links \
		$(if $(UPGRADE),--upgrade) -o requirements.lock pyproject.toml

lock-gpu: ## regenerate requirements-gpu.lock (the CUDA plugin of the pinned jaxlib; needs network)
	@test -x $(BIN)/pip-compile || $(MAKE) install
	$(BIN)/pip-compile --quiet --generate-hashes --allow-unsafe --strip-extras --no-emit-index-url \
		--no-emit-find-links -c requirements.lock -o requirements-gpu.lock requirements-gpu.in

clean: ## remove the venvs and caches (runs/ is kept)
	rm -rf $(VENV) $(LATEST_VENV) .pytest_cache .ruff_cache .mypy_cache docs/_build
