#!/usr/bin/env bash
# The GPU check (issue item 4) as one script, run ON the device machine from the project root,
# within 8 minutes, set-up included, with .gpu/ (ignored) holding the wheels and EGL packages that
# machine lacks: `bash scripts/gpu_check.sh`; `DRY=1 OUT=/tmp/out` rehearses it on a CPU.
# Steps, each with its own time limit (all of them also stop at the 8-minute deadline):
#   1. tests:      a GPU-path subset of the default suite (MJX envs, TD3/DQN probes) with
#                  JAX_DEFAULT_MATMUL_PRECISION=highest; junit XML in $OUT/pytest.xml
#   2. throughput: MJX env steps/s at 1,024-65,536 envs for IP, IDP, HalfCheetah ($OUT/throughput.md)
#   3. updates:    td3_cheetah's default loop (5 seeds), env steps/s and updates/s ($OUT/updates.json)
#   4. recipes:    GPU candidates for half cheetah, 5 seeds each, time to a mean of 5,000
#                  (bench/gpu_recipe.py; $OUT/recipes.md)
# Compiling is CPU work and the machine has 16 cores, so step 1 runs beside the compiles of steps
# 2-4 (their programs then load from the persistent cache); steps 2-4 are timed alone.
# Everything else (each step's log, the recipes' metrics) is in $OUT/logs.tar.gz, so that $OUT
# holds at most 8 files.
# Knobs: PARTS="tests throughput updates recipes" (a subset, e.g. for a second call),
# CANDIDATES=name,name and BASE_SEED=N (bench/gpu_recipe.py: which candidates, which 5 seeds),
# ENVS=name,name (throughput), PYTEST_ARGS, PYTEST_STOP (default --maxfail=10),
# TOTAL (seconds, default 470), P1 (the first step's limit, 150) and P2 (the timed throughput's, 160).
# DRY=1 OUT=/tmp/out bash scripts/gpu_check.sh: the same steps at toy sizes on a CPU (2-4 min),
# one at a time, with .venv's python and a fresh compilation cache, to rehearse the script itself.
set -u
START=$(date +%s)
PARTS=${PARTS:-tests throughput updates recipes}
[ -n "${DRY:-}" ] && OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"

main() {
if [ -n "${DRY:-}" ]; then
  PY=$PWD/.venv/bin/python; [ -x "$PY" ] || PY=python3
  WORK=/tmp/gpu_check_dry
  TOTAL=${TOTAL:-300}
  PARALLEL=0  # 2 cores: the compiles of step 1 one after another, not all at once
  export JAX_COMPILATION_CACHE_DIR=$WORK/jaxcache  # fresh: the warm-then-load path really runs
else
  [ -f .gpu/check.sh ] || { echo "no .gpu/check.sh: put the GPU set-up (wheels, EGL packages, check.sh) into .gpu first"; return 2; }
  # check.sh's set-up (EGL debs, wheels into /tmp/site, PYTHONPATH, MUJOCO_GL, compilation
  # cache), and none of its steps
  STEPS=: source .gpu/check.sh  # defines its own step(): ours is run_step
  PY=python3
  WORK=/tmp/gpu_check
  TOTAL=${TOTAL:-470}
  PARALLEL=1
fi
DEADLINE=$((START + TOTAL))
export PYTHONUNBUFFERED=1
rm -rf "$WORK"; mkdir -p "$WORK/logs"
echo "gpu_check: parts [$PARTS], deadline ${TOTAL}s after the start, set-up took $(( $(date +%s) - START ))s"

# ---- sizes: the check, or its toy rehearsal ----------------------------------------------------
ENVS=${ENVS:-InvertedPendulum-v5,InvertedDoublePendulum-v5,HalfCheetah-v5}
CHEETAH_LOOP='{"actor_hidden": [128, 128], "critic_hidden": [128, 128]}'  # td3_cheetah's default
if [ -n "${DRY:-}" ]; then
  TESTS_DEFAULT="tests/test_bench_env_throughput.py -k over_its_limit"
  ENVS=InvertedPendulum-v5
  SIZES=2
  THROUGHPUT=(--min-time 0.05 --rounds 1 --mjx-limit 120)
  UPDATES=(--seeds 1 --recipe '{"actor_hidden": [16, 16], "critic_hidden": [16, 16], "num_envs": 2, "batch_size": 32, "iterations_per_chunk": 50}')
  RECIPES=(--dry --budget 10)
else
  TESTS_DEFAULT="tests/envs/test_mujoco_env.py tests/envs/test_mujoco_parity.py tests/agents/test_td3_probes.py tests/agents/test_dqn_probes.py -k 'mjx or backends or backend_choice or probes'"
  SIZES=1024,4096,16384,65536
  THROUGHPUT=(--min-time 1 --rounds 1 --mjx-limit 90)  # a GPU to itself: one round suffices
  UPDATES=(--seeds 5 --recipe "$CHEETAH_LOOP")
  RECIPES=(--budget 60)
fi
[ -n "${CANDIDATES:-}" ] && RECIPES+=(--candidates "$CANDIDATES")
[ -n "${BASE_SEED:-}" ] && RECIPES+=(--base-seed "$BASE_SEED")
XDIST=()
[ -z "${DRY:-}" ] && $PY -c "import xdist" 2>/dev/null && XDIST=(-n "${XDIST_N:-4}")

# ---- 1. tests, beside the compiles of steps 2-4 (untimed) ---------------------------------------
P1=${P1:-150}
(
  export XLA_PYTHON_CLIENT_PREALLOCATE=false  # several processes share the GPU here
  if has tests; then
    eval "set -- ${PYTEST_ARGS:-$TESTS_DEFAULT}"  # the quotes of a -k expression survive
    # shellcheck disable=SC2086  # PYTEST_STOP may be empty
    bg run_step tests "$P1" env JAX_DEFAULT_MATMUL_PRECISION=highest $PY -m pytest -q \
      ${PYTEST_STOP---maxfail=10} --timeout 300 -rA --junitxml="$OUT/pytest.xml" "${XDIST[@]}" "$@"
  fi
  if has throughput; then
    for env in ${ENVS//,/ }; do  # one process per env: three compiles at once
      bg run_step "warm-throughput-$env" "$P1" $PY -m bench.bench_env_throughput --backend mjx \
        --envs "$env" --sizes "$SIZES" --min-time 0.01 --rounds 1 --mjx-limit "$P1"
    done
  fi
  has updates && bg run_step warm-updates "$P1" $PY -m bench.cheetah_recipe --measure 1 "${UPDATES[@]}"
  has recipes && bg run_step warm-recipes "$P1" $PY -m bench.gpu_recipe warm --workdir "$WORK/recipes" \
    --timeout "$((P1 - 10))" "${RECIPES[@]}"
  wait
)
snapshot

# ---- 2-4, timed one at a time -------------------------------------------------------------------
if has throughput; then
  run_step throughput "${P2:-160}" $PY -m bench.bench_env_throughput --backend mjx --envs "$ENVS" \
    --sizes "$SIZES" "${THROUGHPUT[@]}" --out "$OUT/throughput.md"
  snapshot
fi
if has updates; then
  run_step updates 60 $PY -m bench.cheetah_recipe --measure 2 "${UPDATES[@]}"
  grep '^{' "$WORK/logs/updates.log" | tail -1 > "$OUT/updates.json"
  snapshot
fi
if has recipes; then
  run_step recipes $((DEADLINE - $(date +%s))) $PY -m bench.gpu_recipe run --workdir "$WORK/recipes" \
    --deadline "$((DEADLINE - 5))" "${RECIPES[@]}"
  $PY -m bench.gpu_recipe table --workdir "$WORK/recipes" "${RECIPES[@]}" > "$OUT/recipes.md"
  snapshot
fi

echo "== summary ($(( $(date +%s) - START ))s in all)"
has tests && grep -E '^(FAILED|ERROR)|(passed|failed|error|skipped|no tests ran).* in [0-9.]+s' \
  "$WORK/logs/tests.log" | tail -30
for f in throughput.md updates.json recipes.md; do
  [ -s "$OUT/$f" ] && { echo "-- $f"; grep -v '^$' "$OUT/$f"; }
done
snapshot
}

has() { [[ " $PARTS " == *" $1 "* ]]; }
bg() { if [ "$PARALLEL" = 1 ]; then "$@" & else "$@"; fi; }  # a step of step 1
snapshot() { # every log and the recipes' metrics (no checkpoints), as one file
  tar czf "$OUT/logs.tar.gz.part" -C "$WORK" --exclude=checkpoints --exclude=best \
    --exclude=jaxcache --exclude=tensorboard --exclude='events.out.*' . 2>/dev/null
  mv -f "$OUT/logs.tar.gz.part" "$OUT/logs.tar.gz"
}
run_step() { # name seconds command...: at most that long (and never past the deadline); SIGINT
  # first, so that pytest still writes its report
  local name=$1 cap=$2; shift 2
  local left=$((DEADLINE - $(date +%s)))
  ((cap > left)) && cap=$left
  if ((cap < 10)); then echo "== $name: not run, the deadline is near"; return; fi
  local t0 rc
  t0=$(date +%s)
  timeout -s INT -k 15 "$cap" "$@" > "$WORK/logs/$name.log" 2>&1; rc=$?
  # one block per step, so that the blocks of parallel steps do not interleave
  printf '== %s rc=%s %ss (limit %ss)\n%s\n' "$name" "$rc" "$(( $(date +%s) - t0 ))" "$cap" \
    "$(tr '\r' '\n' < "$WORK/logs/$name.log" | grep -v -e warp -e '^$' -e '^[EW][0-9]\{4\} ' \
       | tail -"${TAILN:-12}")"
}

# a pipeline into tee, not exec > >(tee): the script then ends only after the log is complete
main 2>&1 | tee "$OUT/gpu_check.log"
exit "${PIPESTATUS[0]}"
