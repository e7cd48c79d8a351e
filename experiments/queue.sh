#!/bin/bash
# The open CPU work (issue 72; issues 54 and 55's lanes are done and kept for a rerun), in lanes that resume from their checkpoints (runs/, this machine's) and
# commit each small result as it lands (only the result files; the rest of the work tree is left as it is):
#
#   bash experiments/queue.sh table    # issue 54: Table 1's DT-family sweep at study, seed 0, then 1, then 2
#   bash experiments/queue.sh curves   # issue 72: the surrogate reward under IQL and TD3+BC, at the last step or
#                                      # spread over the episode (minsubdt-iql vs minsubdt-iql-spread, ...)
#   bash experiments/queue.sh peers    # issue 72: d3rlpy's critic agents on our files (experiments/peer_critics.py)
#   bash experiments/queue.sh v5       # issue 73: hopper medium recorded in gymnasium's v5 (experiments/v5_cell.py)
#   bash experiments/queue.sh behavior # issue 74: SAC behaviour policies at trade-offs of speed and energy
#                                      # (experiments/tradeoff_policies.py), halfcheetah then hopper
#   bash experiments/queue.sh front    # issue 55: the fronts' remaining cells
#   bash experiments/queue.sh status   # what each lane has left, from the committed result files, and the runs
#                                      # under way that this machine's checkpoints resume
#
# In the background, one lane per log (each lane waits while another process runs its own script):
#   mkdir -p runs/logs && for l in curves peers; do
#     nohup setsid bash experiments/queue.sh $l > runs/logs/queue-$l.log 2>&1 & done
# A lane done is a no-op when started again, on any machine: finished units, curves and cells are skipped by their
# committed result files.
set -u
cd "$(dirname "$0")/.."
mkdir -p runs/logs

commit() {  # commit the named result paths if they changed: commit MESSAGE PATH... (experiments/gitcommit.py)
    python experiments/gitcommit.py "$@"
}

wait_for() {  # while another process runs this pattern, wait (the run directories' locks would refuse a second)
    while pgrep -f "$1" > /dev/null; do sleep 60; done
}

log() { echo "[$(date -u +%FT%TZ)] $*"; }

# what the curves and front lanes run (the table lane's cells are table1.py's own), read by status too
# each curve: "env dataset methods steps" at the agent's study setting (its steps, EMA 0.999)
CURVE_CELLS=("walker medium minsubdt-iql,minsubdt-iql-spread 60000" "hopper medium minsubdt-iql,minsubdt-iql-spread 60000"
             "walker medium minsubdt-td3bc,minsubdt-td3bc-spread 100000"
             "hopper medium minsubdt-td3bc,minsubdt-td3bc-spread 100000")
CURVE_FLAGS="--model cpu --eval-every 5000 --chunk-steps 1000 --episodes 30 --seeds 3 --ema 0.999"
# each peer cell: "agent env dataset [flags]" (experiments/peer_critics.py; 3 seeds each side at study unless said)
PEER_CELLS=("td3bc hopper medium" "iql hopper medium" "iql walker medium-replay" "td3bc walker medium-replay"
            "cql hopper medium --steps 20000 --seeds 2 --eval-every 5000"
            "bear hopper medium --steps 30000 --seeds 2 --eval-every 5000")
FRONT_CELLS=("walker medium-replay" "halfcheetah medium-replay" "walker medium")
BEHAVIOR_ENVS=(halfcheetah hopper)  # issue 74: halfcheetah and one of hopper or walker (hopper trains 3x faster)

table() {
    wait_for "experiments/table1.py run"
    for s in 0 1 2; do
        log "table1 --seeds $s"
        python experiments/table1.py run --preset study --commit --seeds "$s" || { log "table1 s$s rc=$?"; return 1; }
        python experiments/table1.py aggregate --preset study > /dev/null  # the report of what has landed
        commit "Table 1 (study): the report after seed $s's pass; resume: bash experiments/queue.sh table" \
            experiments/results/table1.md experiments/results/table1.json experiments/results/table1_costs_*.png \
            experiments/results/table1_curves
    done
}

curves() {
    wait_for "experiments/curves.py run"
    for cell in "${CURVE_CELLS[@]}"; do
        set -- $cell
        log "curve $*"
        python experiments/curves.py run --env "$1" --dataset "$2" --methods "$3" --steps "$4" $CURVE_FLAGS \
            || { log "curve $* rc=$?"; return 1; }
        python experiments/curves.py report > /dev/null
        commit "Curves (issue 72, the surrogate reward under a critic): $*; resume: bash experiments/queue.sh curves" \
            experiments/results/curves experiments/results/curves.md
    done
}

peers() {
    wait_for "experiments/peer_critics.py run"
    [ -x .venv-peer/bin/python ] || { python3 -m venv .venv-peer && .venv-peer/bin/pip install -q -e . d3rlpy==2.8.1 \
        torch; } || { log "peer venv rc=$?"; return 1; }
    for cell in "${PEER_CELLS[@]}"; do
        set -- $cell
        log "peer $*"
        .venv-peer/bin/python experiments/peer_critics.py run --agent "$1" --env "$2" --dataset "$3" "${@:4}" --commit \
            || { log "peer $* rc=$?"; return 1; }
        python experiments/peer_critics.py report > /dev/null
        commit "Peer critics (issue 72): $*; resume: bash experiments/queue.sh peers" \
            experiments/results/peer_critics experiments/results/peer_critics.md
    done
    for agent in td3bc iql cql bear; do
        .venv-peer/bin/python experiments/peer_critics.py time --agent "$agent" --time-steps 300 || return 1
    done
    python experiments/peer_critics.py report > /dev/null
    commit "Peer critics (issue 72): step times; resume: bash experiments/queue.sh peers" \
        experiments/results/peer_critics experiments/results/peer_critics.md
}

v5() {
    wait_for "experiments/v5_cell.py run"
    log "v5 cell"
    python experiments/v5_cell.py run || { log "v5 cell rc=$?"; return 1; }
    commit "v5 cell (issue 73): hopper medium in gymnasium's v5 physics, MinSubDT and DT at study; resume: bash \
experiments/queue.sh v5" experiments/results/v5_cell.json experiments/results/v5_cell.md
}

behavior() {  # each policy committed as it lands (the family and its report) by the script itself
    wait_for "experiments/tradeoff_policies.py run"
    for env in "${BEHAVIOR_ENVS[@]}"; do
        log "trade-off policies $env"
        python experiments/tradeoff_policies.py run --env "$env" --commit || { log "behavior $env rc=$?"; return 1; }
    done
}

front() {
    wait_for "experiments/front.py run"
    # issue 55 yields to issue 54's lanes: under setsid each lane is its own scheduler autogroup, in which
    # nice alone changes nothing, so the autogroup's own nice is raised where the kernel has one
    { echo 5 > /proc/self/autogroup; } 2> /dev/null || true
    for cell in "${FRONT_CELLS[@]}"; do
        set -- $cell
        log "front $1 $2"
        nice -n 5 python experiments/front.py run --env "$1" --dataset "$2" --commit \
            || { log "front $1 $2 rc=$?"; return 1; }
        python experiments/front.py report > /dev/null
        # the report alone: run --commit has committed this cell's file as its parts landed, and another cell's
        # file under way is this machine's (only its vector models may finish the sweeps)
        commit "Front (issue 55): $1 $2 done, and the report; resume: bash experiments/queue.sh front" \
            experiments/results/front.md experiments/results/front.png
    done
}

status() {  # what each lane has left, from the committed result files; this machine's runs under way
    local curves=() fronts=() cell
    for cell in "${CURVE_CELLS[@]}"; do
        set -- $cell
        curves+=("$(python experiments/curves.py name --env "$1" --dataset "$2" --methods "$3" --steps "$4" $CURVE_FLAGS)")
    done
    for cell in "${FRONT_CELLS[@]}"; do fronts+=("${cell// /-}"); done
    PYTHONPATH=experiments python - "${#curves[@]}" "${curves[@]}" "${fronts[@]}" << 'PY'
import glob, json, os, sys

from table1_report import DATASETS, ENVS, METHODS  # the table's DT-family columns and cells

R = "experiments/results"
n = int(sys.argv[1])
curves, fronts = sys.argv[2:2 + n], sys.argv[2 + n:]
have = lambda e, d, s: all(os.path.exists(f"{R}/table1/study/{e}-{d}-{m}-s{s}.json") for m in METHODS)
left = [f"{e}-{d} s{s}" for s in range(3) for e in ENVS for d in DATASETS if not have(e, d, s)]
total = 3 * len(ENVS) * len(DATASETS)
print(f"table: {total - len(left)} of {total} seed-units landed; left: {', '.join(left) or 'none'}")
for name in curves:
    f = f"{R}/curves/{name}.json"
    state = "missing" if not os.path.exists(f) else "partial" if json.load(open(f)).get("partial") else "done"
    print(f"curve {name}: {state}")
print(f"v5 cell: {'done' if os.path.exists(f'{R}/v5_cell.json') else 'missing'}")
for env in ("halfcheetah", "hopper"):
    f = f"src/minsubdt_jax/behavior/snapshots/{env}/tradeoffs/manifest.json"
    got = [p["energy_weight"] for p in json.load(open(f))["policies"]] if os.path.exists(f) else []
    print(f"trade-off policies {env}: lambda {got or 'none'} committed")
peers = sorted(glob.glob(f"{R}/peer_critics/*-*.json"))
for f in (p for p in peers if not os.path.basename(p).startswith("time-")):
    r = json.load(open(f))
    print(f"peer {os.path.basename(f)[:-5]}: d3rlpy seeds {sorted(r['peer'])}, ours {'done' if 'ours' in r else 'missing'}")
for cell in fronts:
    f = f"{R}/front/{cell}.json"
    r = json.load(open(f)) if os.path.exists(f) else {}
    k = {m: len(v) for m, v in r.get("sweeps", {}).items()}
    print(f"front {cell}: targets {k or 'none'}, scalar runs {sorted(r.get('scalar', {})) or 'none'}")
# where this machine's lanes resume from: run directories with checkpoints and no results.json yet
for d in sorted({os.path.dirname(c) for c in glob.glob("runs/**/checkpoints", recursive=True)}):
    steps = [int(s) for s in os.listdir(f"{d}/checkpoints") if s.isdigit()]
    if steps and not os.path.exists(f"{d}/results.json"):
        print(f"this machine's checkpoints: {d} at step {max(steps)}")
PY
}

{  # parsed whole before it runs, and exits: an edit of this file does not reach a lane that is running
    case "${1:-}" in
        table | curves | peers | v5 | behavior | front | status) "$1" ;;
        *) echo "usage: bash experiments/queue.sh table|curves|peers|v5|behavior|front|status" >&2; exit 2 ;;
    esac
    exit
}
