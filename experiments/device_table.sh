#!/usr/bin/env bash
# The GPU's share of Table 1 (issue 58), in one command of at most ~10 minutes that the same command resumes on a warm
# machine. Stages, in order of value, each run while the time left allows its estimate (STAGES="a b" in the
# environment: those only), each finished one tarred into $OUT at once so a lease cut short keeps it:
#   bear-walker, bear-hopper, bear-halfcheetah  BEAR's column at `study` (60k steps: its H200 curve is flat by 42k),
#                                               an env's 3 datasets x 3 seeds as one program (9 models) each
#   cql-300k                                    CQL's curve beyond 60k (not flat there), walker medium, 3 seeds: its
#                                               column needs a flat curve first (device_curves.sh's stage)
#   brac-300k                                   BRAC-v at alpha 1.0 after 14k of behaviour pretraining, 300k, 3 seeds:
#                                               whether its swings at 140k are a phase (docs/convergence.md)
#   paper-walker, paper-hopper, paper-halfcheetah   the paper preset's DT table (the fixed DT): an env's 3 datasets x
#                                               4 methods x 3 seeds in one program (36 models, 100k steps, ~25 min
#                                               each on an H100: three commands in a row per env, each resuming)
# Each table stage is `python experiments/table1.py run ...`: it records the datasets on the machine's CPU cores
# on first use (C MuJoCo), trains, evaluates and writes one small JSON per model under
# experiments/results/table1/<preset>/, which the stage tars with its log.
#
#   on the device tool: carry [".whl"], command
#     source .whl/setup.sh && bash experiments/device_table.sh $OUT 560
#   here: for f in <files_at>/*.tgz; do tar xzf $f; done; python experiments/table1.py aggregate --preset study
#   a dry run here (smoke sizes, ~4 min on 2 cores): PRESET=smoke CURVE_EXTRA="--steps 20 --eval-every 10
#     --episodes 2 --seeds 1 --chunk-steps 10" STAGES="bear-hopper cql-300k" bash experiments/device_table.sh /tmp/o 600
#
# .whl: bash ../shared/device/fetch-wheels.sh (../shared/device/README.md).
set -uo pipefail
out=${1:?usage: device_table.sh OUT_DIR [SECONDS]}
limit=${2:-560}
preset=${PRESET:-study}    # smoke for a dry run: the same stages at seconds' size
mkdir -p "$out"
export JAX_DEFAULT_MATMUL_PRECISION=${JAX_DEFAULT_MATMUL_PRECISION:-highest}  # f32 as the curves that chose 60k
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null | tee "$out/device.txt"
nproc | tee -a "$out/device.txt"

wanted() {  # wanted NAME ESTIMATE: 0 if the stage is asked for and its estimate fits the time left
  local left=$((limit - SECONDS))
  if [ -n "${STAGES:-}" ] && [[ " $STAGES " != *" $1 "* ]]; then
    return 1
  fi
  if ((left < $2)); then
    echo "== skip $1: ${left}s left, estimate ${2}s"
    return 1
  fi
  echo "== $1 (${left}s left, estimate ${2}s)"
}

table() {  # table NAME ESTIMATE PRESET ENV table1.py-flags...: one env's unit, its result files tarred
  local name=$1 est=$2 pre=$3 env=$4
  shift 4
  wanted "$name" "$est" || return 0
  local t0=$SECONDS log="/tmp/device_table_$name.log"
  # shellcheck disable=SC2086
  timeout $((limit - SECONDS - 10)) python experiments/table1.py run --preset "$pre" --envs "$env" --whole-env \
    --physics mujoco "$@" >"$log" 2>&1
  echo "   rc $? after $((SECONDS - t0))s"
  grep -v "it/s\]\|s/it\]\|step/s\]" "$log" | tail -n 3
  local files
  files=$(ls experiments/results/table1/"$pre"/"$env"-*.json 2>/dev/null)
  [ -n "$files" ] && tar czf "$out/$name.tgz" $files "$log" 2>/dev/null
  return 0
}

curve() {  # curve NAME ESTIMATE curves.py-flags...: a score curve, its files tarred as device_curves.sh does
  local name=$1 est=$2
  shift 2
  wanted "$name" "$est" || return 0
  local t0=$SECONDS log="/tmp/device_table_$name.log" base
  # shellcheck disable=SC2086
  timeout $((limit - SECONDS - 10)) python experiments/curves.py run "$@" ${CURVE_EXTRA:-} >"$log" 2>&1
  echo "   rc $? after $((SECONDS - t0))s"
  # shellcheck disable=SC2086
  base=$(python experiments/curves.py name "$@" ${CURVE_EXTRA:-}) && [ -d "runs/curves/$base" ] || return 0
  tar czf "$out/$name.tgz" "runs/curves/$base"/{config.json,dataset.json,metrics.jsonl} "$log" \
    $(ls "experiments/results/curves/$base".{json,png} 2>/dev/null)
}

critic="--env walker --dataset medium --model cpu --steps 300000 --eval-every 30000 --chunk-steps 1000 --episodes 30
  --seeds 3 --ema 0.999 --physics mujoco --tag h200"
# estimates (H200 rates measured in device_curves.sh's leases: BEAR 3 models ~570 program-steps/s, CQL ~355; each
# table stage adds its env's recordings, ~1-3 min on 16 cores): a stage starts only if its estimate fits
table bear-walker 330 "$preset" walker --methods bear
table bear-hopper 330 "$preset" hopper --methods bear
table bear-halfcheetah 330 "$preset" halfcheetah --methods bear
# shellcheck disable=SC2086
curve cql-300k 300 $critic --methods cql
# shellcheck disable=SC2086
curve brac-300k 300 $critic --methods brac-v --brac-alpha 1.0 --pretrain-steps 14000
paper=paper
[ "$preset" = smoke ] && paper=smoke
table paper-walker 500 "$paper" walker --precision bf16
table paper-hopper 500 "$paper" hopper --precision bf16
table paper-halfcheetah 500 "$paper" halfcheetah --precision bf16
echo "== done at ${SECONDS}s"
