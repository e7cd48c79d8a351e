#!/usr/bin/env bash
# Score curves on a GPU machine in one command of at most ~10 minutes (issue 25, item 1): the paper's 128 x 3 model
# and the cpu preset's 64 x 2 on hopper medium-replay and halfcheetah medium-expert, each pair on the same data
# (recorded there, with C MuJoCo: its hash differs from this CPU's, so the files carry --tag h200), then longer
# schedules on walker medium and halfcheetah medium-expert. Stages run in this order while the time left allows
# their estimate (STAGES="a b" in the environment: those only); each finished curve is tarred into $OUT at once
# (JSON, PNG, the run's config, dataset.json, metrics.jsonl and the stage's log), so a cut keeps them.
#
#   on the device tool: carry [".whl"], command
#     source .whl/setup.sh && bash experiments/device_curves.sh $OUT 555
#   (2026-12-04, H200: hmr-paper, hcme-paper, hmr-cpu in 518 s, hcme-cpu in a second command; next:
#     source .whl/setup.sh && STAGES="walker-cpu-50k hcme-cpu-40k" bash experiments/device_curves.sh $OUT 545, 431 s;
#     source .whl/setup.sh && STAGES="walker-cql-60k walker-bear-60k" bash experiments/device_curves.sh $OUT 340:
#     CQL in 264 s, BEAR skipped for time; a third lease:
#     source .whl/setup.sh && STAGES="walker-paper-50k" bash experiments/device_curves.sh $OUT 560, 503 s;
#     source .whl/setup.sh && STAGES="walker-bear-60k" bash experiments/device_curves.sh $OUT 290, 187 s;
#     not run yet: STAGES="walker-paper-100k" (twice) and STAGES="walker-cql-300k" (two or three times), each
#     command $OUT 555 on a warm machine, the next one at once: idle_release_s is 30)
#   here: for f in <files_at>/*.tgz; do tar xzf $f; done; python experiments/curves.py report
#
# .whl: bash ../shared/device/fetch-wheels.sh (../shared/device/README.md). EXTRA (env) is appended to every
# curves.py command: a smoke test here, e.g. EXTRA="--steps 20 --eval-every 10 --episodes 2 --seeds 1".
set -uo pipefail
out=${1:?usage: device_curves.sh OUT_DIR [SECONDS]}
limit=${2:-560}
mkdir -p "$out"
export JAX_DEFAULT_MATMUL_PRECISION=${JAX_DEFAULT_MATMUL_PRECISION:-highest}  # f32 as on the CPU, not TF32
common="--episodes 30 --seeds 3 --lr-schedule cosine --ema 0.999 --physics mujoco --tag h200"
constant="--episodes 30 --seeds 3 --ema 0.999 --physics mujoco --tag h200"  # the same at a constant rate
paper="--model paper --steps 10000 --warmup 500 --eval-every 2000"  # the walker medium 128 x 3 curve's flags
cpu="--model cpu --steps 10000 --eval-every 1000"                    # the 64 x 2 curves' flags
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null | tee "$out/device.txt"
nproc | tee -a "$out/device.txt"

stage() {  # stage TAR_NAME ESTIMATE_SECONDS curves.py-flags...
  local name=$1 est=$2
  shift 2
  local left=$((limit - SECONDS))
  if [ -n "${STAGES:-}" ] && [[ " $STAGES " != *" $name "* ]]; then
    return
  fi
  if ((left < est)); then
    echo "== skip $name: ${left}s left, estimate ${est}s"
    return
  fi
  echo "== $name (${left}s left, estimate ${est}s): python experiments/curves.py run $* ${EXTRA:-}"
  local t0=$SECONDS log=/tmp/device_curves_$name.log base
  # shellcheck disable=SC2086
  timeout $((left - 10)) python experiments/curves.py run "$@" ${EXTRA:-} >"$log" 2>&1
  echo "   rc $? after $((SECONDS - t0))s"
  grep -v "it/s\]\|s/it\]" "$log" | tail -n 4
  # shellcheck disable=SC2086
  base=$(python experiments/curves.py name "$@" ${EXTRA:-}) && [ -d "runs/curves/$base" ] || return
  cp "$log" "runs/curves/$base/device_curves.log"  # beside its run (runs/ is ignored), not in the repo root
  tar czf "$out/$name.tgz" "runs/curves/$base"/{config.json,dataset.json,metrics.jsonl,device_curves.log} \
    $(ls "experiments/results/curves/$base".{json,png} 2>/dev/null)
}

# shellcheck disable=SC2086
{
  stage hmr-paper 150 --env hopper --dataset medium-replay $paper $common
  stage hcme-paper 200 --env halfcheetah --dataset medium-expert $paper $common
  stage hmr-cpu 120 --env hopper --dataset medium-replay $cpu $common
  stage hcme-cpu 120 --env halfcheetah --dataset medium-expert $cpu $common
  stage walker-cpu-50k 200 --env walker --dataset medium --model cpu --steps 50000 --eval-every 5000 \
    --chunk-steps 1000 --methods minsubdt,dt,bc $common
  stage hcme-cpu-40k 160 --env halfcheetah --dataset medium-expert --model cpu --steps 40000 --eval-every 4000 \
    --chunk-steps 1000 $common
  stage walker-paper-50k 420 --env walker --dataset medium --model paper --steps 50000 --warmup 500 \
    --eval-every 5000 --chunk-steps 1000 --methods minsubdt,dt,bc $common  # walker-cpu-50k at 128 x 3 (lr 1e-4)
  # the paper's own schedule (constant rate after a 10k warm-up, 100k steps), raw and EMA parameters scored; ~560 s
  # in all, more than one command: the estimate lets it start, and the same command again resumes it (warm machine)
  stage walker-paper-100k 300 --env walker --dataset medium --model paper --steps 100000 --eval-every 10000 \
    --chunk-steps 1000 --methods minsubdt,dt $constant
  critic() {  # critic STEPS: the CPU critic curves' flags (constant rates), 10 evaluations
    echo "--env walker --dataset medium --model cpu --steps $1 --eval-every $(($1 / 10)) --chunk-steps 1000 $constant"
  }
  stage walker-cql-60k 200 $(critic 60000) --methods cql  # CQL has no curve on the CPU (~6k steps per 10 CPU-min)
  stage walker-bear-60k 150 $(critic 60000) --methods bear  # the CPU's BEAR curve stops at 21k, still rising
  # CQL's 60k curve still moved (docs/convergence.md): 5x the steps, ~14 min of training for 3 models, so two or
  # three commands in a row, each resuming the last (like walker-paper-100k)
  stage walker-cql-300k 300 $(critic 300000) --methods cql
}
echo "== done at ${SECONDS}s"
