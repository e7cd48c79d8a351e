"""Trade-offs in metric space: MinSubDT trained on {forward speed, control energy} and on forward speed alone.

    python experiments/tradeoff.py run              # both agents, 3 seeds each, then the report (resumable)
    python experiments/tradeoff.py report           # experiments/results/tradeoff.{md,png} from the results present

``run`` trains MinSubDT (``--method minsubdt``) on ``--env`` / ``--dataset`` twice: with ``--costs
x_velocity,energy`` and with ``--costs x_velocity``, ``--seeds`` seeds each at the ``cpu`` preset's model for
``--steps`` steps, and scores every rollout on both metrics (``--eval-costs x_velocity,energy``). Each finished run
leaves ``experiments/results/tradeoff/<costs>.json`` (the command, the data file's hash, and every rollout's two
costs); a cut run resumes from ``runs/tradeoff/<costs>``.

``report`` draws the demos and the rollouts in the plane of the two costs (lower is better on both), with the
demos' non-dominated front and their mean, and counts, per agent, the rollouts that dominate the mean demo (no
cost worse, one better) and those no demo dominates (on or beyond the front).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results", "tradeoff")
PAIR = ("x_velocity", "energy")
AGENTS = {"x_velocity,energy": "speed + energy", "x_velocity": "speed alone"}


def run(a) -> None:
    from minsubdt_jax.config import PRESETS, validate
    from minsubdt_jax.train import train

    os.makedirs(RESULTS, exist_ok=True)
    for costs in AGENTS:
        name = costs.replace(",", "+")
        out = os.path.join(a.runs_root, name)
        cfg = dataclasses.replace(PRESETS["cpu"], env=a.env, dataset=a.dataset, method="minsubdt", seed=0,
                                  seeds=a.seeds, steps=a.steps, eval_episodes=a.episodes, costs=costs,
                                  eval_costs=",".join(PAIR), physics=a.physics, out=out)
        if os.path.exists(os.path.join(out, "results.json")) and os.path.exists(os.path.join(RESULTS, name + ".json")):
            continue
        res = train(validate(cfg), resume=os.path.exists(os.path.join(out, "config.json")))
        per = res["eval_per_seed"]
        keep = {"command": " ".join(["python experiments/tradeoff.py", *sys.argv[1:]]), "costs": costs,
                "config": res["config"], "physics": res["physics"],
                "dataset": {k: res["dataset"][k] for k in ("path", "sha256", "episodes", "normalized_score_mean")},
                "cost_metrics": res["dataset"]["cost_metrics"],
                "seeds": [{"seed": e["seed"], "normalized_score_mean": e["normalized_score_mean"],
                           "costs_mean": e["costs_mean"],
                           "costs": [[c[list(e["costs_mean"]).index(n)] for n in PAIR] for c in e["costs"]]}
                          for e in per]}
        with open(os.path.join(RESULTS, name + ".json"), "w") as f:
            json.dump(keep, f, indent=1)


def front(points: np.ndarray) -> np.ndarray:
    """The non-dominated rows of ``points [n, 2]`` (lower is better on both), sorted by the first cost."""
    p = points[np.lexsort((points[:, 1], points[:, 0]))]
    keep, best = [], np.inf
    for row in p:
        if row[1] < best:
            keep.append(row)
            best = row[1]
    return np.array(keep)


def dominated_by_any(points: np.ndarray, demos: np.ndarray) -> np.ndarray:
    """``[n]``: some demo is no worse on both costs and better on one."""
    le = np.all(demos[None, :, :] <= points[:, None, :], axis=2)
    lt = np.any(demos[None, :, :] < points[:, None, :], axis=2)
    return np.any(le & lt, axis=1)


def report(a) -> str:
    from minsubdt_jax.costs import trajectory_costs, cost_metrics
    from minsubdt_jax.data import resolve_dataset

    runs = {}
    for costs in AGENTS:
        path = os.path.join(RESULTS, costs.replace(",", "+") + ".json")
        if os.path.exists(path):
            with open(path) as f:
                runs[costs] = json.load(f)
    if not runs:
        raise SystemExit("no results under experiments/results/tradeoff/: run `python experiments/tradeoff.py run`")
    first = next(iter(runs.values()))
    env = first["config"]["env"]
    f = resolve_dataset(env, first["config"]["dataset"], verbose=False, physics=first["config"]["physics"])
    if f.sha256 != first["dataset"]["sha256"]:
        raise SystemExit(f"the local {f.path} (sha256 {f.sha256[:12]}) is not the data the runs trained on "
                         f"({first['dataset']['sha256'][:12]})")
    d = f.data
    demos = np.asarray(trajectory_costs(cost_metrics(env, ",".join(PAIR)), d.observations, d.lengths,
                                        first["config"]["episode_length"], terminated=d.terminals, actions=d.actions))
    mean, fr = demos.mean(0), front(demos)
    fit = np.polyfit(demos[:, 0], demos[:, 1], 1)  # the demos' energy cost as a line in their speed cost
    valid = np.arange(d.actions.shape[1])[None] < d.lengths[:, None]
    demo_energy = (float(mean[1]), float((d.actions ** 2).mean(-1)[valid].mean()))  # cost; mean a^2 over steps lived
    rows = []
    for costs, r in runs.items():
        pts = np.array([c for s in r["seeds"] for c in s["costs"]])
        beats = np.all(pts <= mean, 1) & np.any(pts < mean, 1)
        free = ~dominated_by_any(pts, demos)
        below = pts[:, 1] < np.polyval(fit, pts[:, 0])  # less energy than the demos' line at the same speed cost
        scores = [s["normalized_score_mean"] for s in r["seeds"]]
        per_seed = np.array([np.mean(s["costs"], axis=0) for s in r["seeds"]])  # [S, 2]
        rows.append({"agent": AGENTS[costs], "costs": costs, "rollouts": len(pts), "seeds": len(r["seeds"]),
                     "score_mean": float(np.mean(scores)), "score_std": float(np.std(scores)),
                     "x_velocity": float(pts[:, 0].mean()), "energy": float(pts[:, 1].mean()),
                     "x_velocity_std": float(per_seed[:, 0].std()), "energy_std": float(per_seed[:, 1].std()),
                     "dominate_mean_demo": float(beats.mean()), "below_demo_line": float(below.mean()), "undominated_by_demos": float(free.mean()), "pts": pts})
    _plot(demos, fr, mean, rows, env, first, os.path.join(HERE, "results", "tradeoff.png"))
    c = first["config"]
    lines = ["# Trade-offs in metric space: speed and energy", "",
             f"`{first['command']}`, then `python experiments/tradeoff.py report`.", "",
             f"MinSubDT on {env} {c['dataset']} (`{os.path.basename(f.path)}`, sha256 {f.sha256[:12]}, "
             f"{d.num_trajectories} episodes), DT {c['embed_dim']}x{c['n_layers']}, {c['steps']} steps "
             f"(the cpu preset's model, not a converged result), {c['eval_episodes']} episodes per seed, "
             f"{first['physics']['physics']} physics. Costs lower-is-better in [0, 1]: "
             + "; ".join(f"`{m['name']}` {m['meaning']}" for m in first["cost_metrics"] if m["name"] in PAIR)
             + " (a fall is charged 1 for every step not lived, on both).", "",
             "![trade-off](tradeoff.png)", "",
             f"Demos: mean x_velocity cost {mean[0]:.3f}, energy {mean[1]:.3f}; {len(fr)} demos on the non-dominated "
             "front.", "",
             "Means over all rollouts, ± the std over seeds of the seed means; the last column: rollouts below the demos' "
             "least-squares line of energy cost on speed cost.", "",
             "| agent (`--costs`) | seeds x episodes | normalised score | x_velocity cost | energy cost | "
             "dominate the mean demo | no demo dominates them | less energy than the demos at their speed |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['agent']} (`{r['costs']}`) | {r['seeds']} x {r['rollouts'] // r['seeds']} | "
              f"{r['score_mean']:.1f} ± {r['score_std']:.1f} | {r['x_velocity']:.3f} ± {r['x_velocity_std']:.3f} | "
              f"{r['energy']:.3f} ± {r['energy_std']:.3f} | "
              f"{100 * r['dominate_mean_demo']:.0f} % | {100 * r['undominated_by_demos']:.0f} % | "
              f"{100 * r['below_demo_line']:.0f} % |" for r in rows]
    if len(rows) == 2:
        both, alone = rows
        lines += ["", "What it shows: " + verdict(both, alone, demo_energy)]
    text = "\n".join(lines) + "\n"
    with open(os.path.join(HERE, "results", "tradeoff.md"), "w") as fh:
        fh.write(text)
    return text


def verdict(both: dict, alone: dict, demo_energy: tuple[float, float]) -> str:
    """One plain sentence from the numbers (written out, not chosen)."""
    better = lambda k: "lower" if both[k] < alone[k] else "higher"  # noqa: E731
    spread = max(both["energy_std"], alone["energy_std"])
    within = abs(both["energy"] - alone["energy"]) < spread
    return (f"the two-metric agent's rollouts have {better('energy')} energy cost ({both['energy']:.3f} vs "
            f"{alone['energy']:.3f}) and {better('x_velocity')} speed cost ({both['x_velocity']:.3f} vs "
            f"{alone['x_velocity']:.3f}) than the speed-only agent's; {100 * both['dominate_mean_demo']:.0f} % vs "
            f"{100 * alone['dominate_mean_demo']:.0f} % of them dominate the mean demo on both costs, and "
            f"{100 * both['undominated_by_demos']:.0f} % vs {100 * alone['undominated_by_demos']:.0f} % lie on or "
            f"beyond the demos' front. The energy difference ({abs(both['energy'] - alone['energy']):.3f}) is "
            f"{'within' if within else 'beyond'} the spread between seeds ({spread:.3f}). Both agents' rollouts "
            f"spend less energy than the demos at the same speed ({100 * both['below_demo_line']:.0f} % and "
            f"{100 * alone['below_demo_line']:.0f} % lie below the demos' least-squares line of energy cost on speed "
            f"cost), the speed-only agent too: that frugality is not what the energy metric taught (a policy fitted "
            f"by mean-squared regression acts the demos' mean action, whose square is below their mean square). A "
            f"fall is charged the "
            f"worst cost on both metrics for every step not lived, so at this stage of training both costs mostly "
            f"measure how long the walker stays up (the demos' mean energy cost {demo_energy[0]:.3f} against "
            f"{demo_energy[1]:.3f} for their mean a^2 over the steps lived): a frugal gait shows in the energy cost "
            f"only once falls are rare.")


def _plot(demos, fr, mean, rows, env, first, png) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 5))
    ax.scatter(demos[:, 0], demos[:, 1], s=4, color="0.75", label=f"demos ({len(demos)})")
    ax.plot(fr[:, 0], fr[:, 1], color="k", lw=1.5, drawstyle="steps-post", label="demos' non-dominated front")
    ax.scatter(*mean, marker="*", s=200, color="k", label="mean demo")
    for k, r in enumerate(rows):
        ax.scatter(r["pts"][:, 0], r["pts"][:, 1], s=14, color=f"C{k}", alpha=0.7,
                   label=f"MinSubDT, {r['agent']} ({r['rollouts']} rollouts)")
    ax.set(xlabel="x_velocity cost (lower: faster)", ylabel="energy cost (lower: less control energy)",
           title=f"{env} {first['config']['dataset']}: demos and rollouts in metric space")
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=["run", "report"])
    p.add_argument("--env", default="walker")
    p.add_argument("--dataset", default="medium")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--steps", type=int, default=5000)
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--physics", default="auto", choices=["auto", "mjx", "mujoco"])
    p.add_argument("--runs-root", default="runs/tradeoff")
    a = p.parse_args(argv)
    if a.action == "run":
        run(a)
    print(report(a))
    return 0


if __name__ == "__main__":
    sys.exit(main())
