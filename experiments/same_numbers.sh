#!/usr/bin/env bash
# Does a refactor keep every number? (issue 57) The same six runs with the code at REV (a git worktree) and with
# the work tree, compared exactly by experiments/compare_runs.py: parameters, losses, evaluation returns.
#   bash experiments/same_numbers.sh REV [OUT_DIR]      # exit 0 if all six are identical
# The runs: the smoke preset on hopper with two DT-family methods x 2 seeds and periodic evaluation, TD3+BC, two
# datasets in one program, the per-metric methods (minsubdt-vec, dt-vec), the cpu preset over 1000 steps, and AWR
# (its own chunk) x 2 seeds.
# Compare on one machine: XLA and the physics are not bit-stable across CPUs.
set -uo pipefail
rev=${1:?usage: same_numbers.sh REV [OUT_DIR]}
out=${2:-$(mktemp -d)}
here=$(cd "$(dirname "$0")/.." && pwd)
tree="$out/tree-$rev"
git -C "$here" worktree add -f -q "$tree" "$rev" || exit 2
runs() {  # runs PREFIX: the six runs, in the current directory's code (PYTHONPATH picks the tree)
  local p=$1 s="--preset smoke --env hopper --episode-length 60 --dataset-transitions 2000"
  python -m minsubdt_jax.train $s --method minsubdt,dt --seeds 2 --eval-every 10 --out "$p-a" >"$p-a.log" 2>&1
  python -m minsubdt_jax.train $s --method td3bc --out "$p-b" >"$p-b.log" 2>&1
  python -m minsubdt_jax.train $s --dataset medium,medium-replay --method minsubdt --out "$p-c" >"$p-c.log" 2>&1
  python -m minsubdt_jax.train $s --method minsubdt-vec,dt-vec --costs x_velocity,energy@lived --out "$p-d" \
    >"$p-d.log" 2>&1
  python -m minsubdt_jax.train --preset cpu --env hopper --steps 1000 --eval-episodes 5 --method minsubdt \
    --out "$p-e" >"$p-e.log" 2>&1
  python -m minsubdt_jax.train $s --method awr --seeds 2 --out "$p-f" >"$p-f.log" 2>&1
}
(cd "$tree" && PYTHONPATH="$tree/src" runs "$out/ref")
(cd "$here" && PYTHONPATH="$here/src" runs "$out/new")
git -C "$here" worktree remove --force "$tree"
rc=0
for x in a b c d e f; do
  report=$(python "$here/experiments/compare_runs.py" "$out/ref-$x" "$out/new-$x" 2>/dev/null)
  if [[ $report == *'"identical": true'* ]]; then
    echo "run $x: identical"
  else
    echo "run $x: DIFFERS (see $out/ref-$x, $out/new-$x)"
    rc=1
  fi
done
exit $rc
