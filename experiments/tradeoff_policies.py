"""Behaviour policies at trade-offs between speed and energy (issue 74): SAC at each energy weight of
``behavior.tradeoffs.ENERGY_WEIGHTS``, each exported into the env's committed trade-off family as it finishes, and
the behaviour front (a figure, and a table of each policy's objectives).

    python experiments/tradeoff_policies.py run --env halfcheetah --commit   # train (resumes), export, commit each
    python experiments/tradeoff_policies.py report                          # results/tradeoff_policies.{md,png}

A weight already in the committed family is not trained again (its run directory may be on another machine);
``runs/behavior-mo/{env}/lambda{w}`` holds each run and its checkpoints (``--resume`` continues one).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results", "tradeoff_policies")
STEPS = {"halfcheetah": 200_000, "hopper": 200_000, "walker": 700_000}  # docs/FIDELITY.md: where SAC got expert


def run_dir(env: str, weight: float) -> str:
    return os.path.join("runs", "behavior-mo", env, f"lambda{weight:g}")


def finished(out: str, steps: int) -> bool:
    path = os.path.join(out, "snapshots.jsonl")
    if not os.path.exists(path):
        return False
    with open(path) as f:
        rows = [json.loads(ln) for ln in f if ln.strip()]
    return bool(rows) and rows[-1]["step"] >= steps


def run(a) -> None:
    from minsubdt_jax.behavior import tradeoffs

    steps = a.steps or STEPS[a.env]
    for weight in a.weights or tradeoffs.ENERGY_WEIGHTS[a.env]:
        try:
            if weight in {p["energy_weight"] for p in tradeoffs.load_manifest(a.env)["policies"]}:
                continue  # committed
        except ValueError:
            pass  # no family yet
        out = run_dir(a.env, weight)
        if not finished(out, steps):
            cmd = [sys.executable, "-m", "minsubdt_jax.behavior.train", "--env", a.env, "--energy-weight", str(weight),
                   "--steps", str(steps), "--out", out]
            subprocess.run(cmd + (["--resume"] if os.path.exists(os.path.join(out, "config.json")) else []), check=True)
        tradeoffs.export(a.env, [out], episodes=a.episodes)
        report(a)
        if a.commit:
            from gitcommit import commit_results

            commit_results([tradeoffs.family_dir(a.env), RESULTS, RESULTS + ".md"],
                           f"Trade-off behaviour policies (issue 74): {a.env} lambda {weight:g}; resume: bash "
                           f"experiments/queue.sh behavior")


def report(a=None) -> str:
    """``results/tradeoff_policies.md`` and one figure per env: each committed policy's speed against its energy
    (episode sums, mean ± std over the export's episodes), labelled with its energy weight."""
    from minsubdt_jax.atomic import save_figure, write_atomic
    from minsubdt_jax.behavior import tradeoffs
    from minsubdt_jax.envs import ENVS

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines = ["# Behaviour policies at trade-offs between speed and energy (issue 74)", "",
             "SAC on r = v_x − λ‖a‖² (+ the healthy reward of hopper and walker), one run per λ; each exported at its "
             "best training objective and measured on the stochastic actor's 1000-step episodes "
             "(`python experiments/tradeoff_policies.py run --env ENV`). Speed and energy are episode sums of v_x "
             "and ‖a‖²: a front runs from fast and costly to slow and frugal.", ""]
    os.makedirs(RESULTS, exist_ok=True)
    for env in ENVS:
        try:
            m = tradeoffs.load_manifest(env)
        except ValueError:
            continue
        lines += [f"## {env}", "", "| λ | preference (speed, energy) | step | speed | energy | return | length |",
                  "|---|---|---|---|---|---|---|"]
        fig, ax = plt.subplots(figsize=(5, 4))
        for p in m["policies"]:
            x = p["measured"]
            lines.append(f"| {p['energy_weight']:g} | {p['preference'][0]:.2f}, {p['preference'][1]:.2f} | "
                         f"{p['step']} | {x['speed_mean']:.0f} ± {x['speed_std']:.0f} | {x['energy_mean']:.0f} ± "
                         f"{x['energy_std']:.0f} | {x['return_mean']:.0f} | {x['length_mean']:.0f} |")
            ax.errorbar(x["energy_mean"], x["speed_mean"], xerr=x["energy_std"], yerr=x["speed_std"], fmt="o")
            ax.annotate(f"λ={p['energy_weight']:g}", (x["energy_mean"], x["speed_mean"]), fontsize=8)
        ax.set(xlabel="energy (episode sum of ‖a‖²)", ylabel="speed (episode sum of v_x)", title=f"{env}: behaviour front")
        save_figure(fig, os.path.join(RESULTS, f"{env}.png"))
        plt.close(fig)
        lines += ["", f"![{env}](tradeoff_policies/{env}.png)", ""]
    text = "\n".join(lines) + "\n"
    write_atomic(RESULTS + ".md", text)
    return text


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--env", required=True, choices=tuple(STEPS))
    r.add_argument("--steps", type=int, default=None, help="SAC env steps per policy (default: STEPS[env])")
    r.add_argument("--weights", type=float, nargs="+", default=None, help="default: tradeoffs.ENERGY_WEIGHTS[env]")
    r.add_argument("--episodes", type=int, default=100, help="episodes each exported policy is measured on")
    r.add_argument("--commit", action="store_true", help="commit the family and the report after each policy")
    sub.add_parser("report")
    a = p.parse_args(argv)
    if a.cmd == "run":
        run(a)
    else:
        print(report(a))


if __name__ == "__main__":
    main()
