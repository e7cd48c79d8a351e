"""One cell on data recorded in gymnasium's v5 physics, as Minari's are (issue 73): our medium behaviour policy in
``Hopper-v5`` (D4RL's size), made a local Minari dataset with references measured in the same env, trained on
with no ``--dynamics`` (MinSubDT and DT at ``study``, 3 seeds x 100 episodes), beside the brax-dynamics cell of
the same recipe (``results/table1.md``).

    python experiments/v5_cell.py run        # record (once), check the dynamics, train (resumes), write the report
    python experiments/v5_cell.py report     # results/v5_cell.md from results/v5_cell.json

Everything it makes lives under ``runs/v5/`` (the recording, the Minari dataset, the run); the small result is
``experiments/results/v5_cell.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join("runs", "v5")
FILE = os.path.join(ROOT, "hopper-v5-medium.hdf5")
DATASET = "minsubdt/hopper-v5/medium-v0"
RUN = os.path.join(ROOT, "hopper-medium-study")
RESULT = os.path.join(HERE, "results", "v5_cell.json")


def run(a) -> dict:
    os.environ["MINARI_DATASETS_PATH"] = os.path.abspath(os.path.join(ROOT, "minari"))
    py = sys.executable
    if not os.path.exists(os.path.join(ROOT, "minari", DATASET)):
        subprocess.run([py, os.path.join(HERE, "gymnasium_dataset.py"), "--env", "hopper", "--version", "v5",
                        "--policy", "medium", "--transitions", str(a.transitions), "--out", FILE, "--minari", DATASET,
                        "--ref-episodes", "100"], check=True)
    check = subprocess.run([py, "-m", "minsubdt_jax.data", "--env", "hopper", "--dataset", FILE, "--check-dynamics"],
                           check=True, capture_output=True, text=True).stdout.strip().splitlines()[-1]
    cmd = [py, "-m", "minsubdt_jax.train", "--env", "hopper", "--dataset", f"minari:{DATASET}", "--method",
           "minsubdt,dt", "--preset", "study", "--seeds", "3", "--out", RUN]
    if not os.path.exists(os.path.join(RUN, "results.json")):
        subprocess.run(cmd + (["--resume"] if os.path.exists(os.path.join(RUN, "config.json")) else []), check=True)
    with open(os.path.join(RUN, "results.json")) as f:
        res = json.load(f)
    out = {"command": "python experiments/v5_cell.py run", "check_dynamics": json.loads(check),
           "train_command": " ".join(["python"] + cmd[1:]), "dataset": res["dataset"], "references": res["references"],
           "physics": res["physics"], "eval_by_method": {m: {k: e[k] for k in (
               "normalized_score_mean", "normalized_score_std", "normalized_score_per_seed", "return_mean",
               "length_mean", "min_subdominance_mean", "better_than_mean_demo_share")}
               for m, e in res["eval_by_method"].items()}}
    from minsubdt_jax.atomic import write_atomic
    write_atomic(RESULT, json.dumps(out, indent=1))
    return report(a)


def report(a) -> str:
    with open(RESULT) as f:
        r = json.load(f)
    with open(os.path.join(HERE, "results", "table1.json")) as f:
        brax = json.load(f)["table"]["medium/hopper"]  # method -> mean, std over its seeds
    chk, ds, refs = r["check_dynamics"], r["dataset"], r["references"]
    lines = ["# Hopper medium recorded in gymnasium's v5 physics, beside the brax-dynamics cell", "",
             f"`{r['command']}` (the recording: `experiments/gymnasium_dataset.py --version v5 --policy medium`, D4RL's "
             f"size, as a local Minari dataset `{DATASET}`; then `{r['train_command']}`, no `--dynamics`).", "",
             f"- The dynamics check on the file: best **{chk['best']}** (" + ", ".join(
                 f"{k} {100 * v['reproduced']:.0f} % reproduced" for k, v in chk["dynamics"].items()) + "; d4rl and v5 "
             "step the same states, and the terminal steps' rewards tell them apart: largest |Δreward| " + ", ".join(
                 f"{k} {chk['dynamics'][k].get('terminal_reward_error', float('nan')):.2g}" for k in chk.get(
                     "same_states", [])) + ").",
             f"- The run evaluated in **{r['physics']['dynamics']}** dynamics ({r['physics']['dynamics_from']['how']}) "
             f"and normalised with {refs['source']}: random {refs['random']:.1f}, expert {refs['expert']:.1f}.",
             f"- The data: {ds['episodes']} episodes, {ds['transitions']} transitions, normalised "
             f"{ds['normalized_score_mean']:.1f}; Spearman(−min-subdominance, return) "
             f"{ds['spearman_neg_min_subdominance_vs_return']:.3f}.", "",
             "| method | v5 physics (this cell) | brax dynamics (Table 1, `study`) |", "|---|---|---|"]
    for m, e in r["eval_by_method"].items():
        b = brax.get(m, {})
        per = ", ".join(f"{x:.1f}" for x in e["normalized_score_per_seed"])
        lines.append(f"| {m} | {e['normalized_score_mean']:.1f} ± {e['normalized_score_std']:.1f} ({per}); length "
                     f"{e['length_mean']:.0f} | " + (f"{b['mean']:.1f} ± {b['std']:.1f}" if b else "–") + " |")
    text = "\n".join(lines) + "\n"
    from minsubdt_jax.atomic import write_atomic
    write_atomic(os.path.join(HERE, "results", "v5_cell.md"), text)
    print(text)
    return text


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("command", choices=("run", "report"))
    p.add_argument("--transitions", type=int, default=1_000_000)
    a = p.parse_args(argv)
    {"run": run, "report": report}[a.command](a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
