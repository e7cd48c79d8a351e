"""Fronts' report (issue 55): ``experiments/results/front.{md,png}`` from the cells' results files that
``experiments/front.py run`` writes: per cell, the hypervolume (moocore; reference point 1 in both costs, lower is
better) of the non-dominated points of the demos, of the scalar runs' means, and of each vector method's target sweep
(the means over seeds per target; and per seed, mean +- std), the Spearman per metric between the target and the
achieved cost over the grid and within its rows (the other metric's target held), and a figure of the demos and the
rollout means in the plane of the two costs. Run as ``python experiments/front.py report``."""

from __future__ import annotations

import json
import os

import numpy as np

from minsubdt_jax.atomic import atomic_open, save_figure

HERE = os.path.dirname(os.path.abspath(__file__))  # experiments/
RESULTS = os.path.join(HERE, "results", "front")  # the cells' files
PAIR = ("x_velocity", "energy@lived")  # the two cost metrics of every front


def hypervolume(points) -> float:
    """Hypervolume dominated by ``points [n, 2]`` (costs, lower is better) up to the reference point (1, 1),
    clipped into [0, 1] (moocore: it keeps the non-dominated points itself)."""
    try:
        import moocore
    except ImportError:
        raise SystemExit("the hypervolume needs moocore: pip install -e '.[front]'") from None
    p = np.clip(np.asarray(points, np.float64).reshape(-1, 2), 0.0, 1.0)
    return float(moocore.hypervolume(p, ref=[1.0, 1.0]))


def steering(t, c, k: int, held: bool = False) -> float:
    """How metric ``k``'s target steers its achieved cost: the Spearman between the two over the whole grid, or with
    ``held`` within each group of targets that share the other metric's target; mean over the groups and seeds.
    ``t [n, 2]`` the targets, ``c [n, seeds, 2]`` the achieved costs."""
    from minsubdt_jax.costs import spearman

    group = t[:, 1 - k] if held else np.zeros(len(t))
    return float(np.mean([spearman(t[group == v, k], c[group == v, s, k])
                          for v in np.unique(group) for s in range(c.shape[1])]))


def cell_report(r: dict) -> tuple[list[str], dict]:
    """One cell's section of front.md from its results file ``r``, and its points for the figure ``{label: [n, 2]}``."""
    rows, notes, pts = [], [], {"demos": np.asarray(r["demo_costs"])}
    rows.append(f"| demos ({len(r['demo_costs'])} episodes) | {hypervolume(pts['demos']):.3f} | "
                "– | – | – | – | – |")
    if r.get("scalar"):
        scal = np.array([np.mean(v["costs"], 0) for v in r["scalar"].values()])
        pts["scalar MinSubDT"] = scal
        per = np.array([[hypervolume([np.asarray(v["costs"])[s] for v in r["scalar"].values()])
                         for s in range(r["seeds"])]])
        rows.append(f"| scalar MinSubDT ({', '.join(k.removeprefix('minsubdt-') for k in r['scalar'])}) | "
                    f"{hypervolume(scal):.3f} | {per.mean():.3f} ± {per.std():.3f} | – | – | – | – |")
    for method, sweep in r.get("sweeps", {}).items():
        c = np.array([s["costs"] for s in sweep])  # [targets, seeds, 2]
        t = np.array([[s["target"][m] for m in PAIR] for s in sweep])
        pts[method] = c.mean(1)
        hv_seed = np.array([hypervolume(c[:, s]) for s in range(c.shape[1])])
        rho, held = ([steering(t, c, k, h) for k in range(2)] for h in (False, True))
        rows.append(f"| `{method}` ({len(sweep)} targets) | {hypervolume(c.mean(1)):.3f} | {hv_seed.mean():.3f} ± "
                    f"{hv_seed.std():.3f} | {rho[0]:+.2f} | {rho[1]:+.2f} | {held[0]:+.2f} | {held[1]:+.2f} |")
        notes.append(beyond_demos(method, c.mean(1), pts["demos"]))
    head = [f"### {r['cell']} ({r['preset']}, {r['seeds']} seeds x {r['episodes']} episodes per target)", "",
            f"`{r['command']}`", "",
            f"| points | hypervolume of the means | per seed | Spearman(target, cost) {PAIR[0]} | {PAIR[1]} | "
            f"other target held: {PAIR[0]} | {PAIR[1]} |", "|---|---|---|---|---|---|---|"]
    notes += [scalar_subdominance(r) if r.get("scalar") else "", reach(pts), recordings(r)]
    return head + rows + ["", demos_trade_off(pts["demos"]), ""] + [x for n in notes if n for x in (n, "")], pts


def scalar_subdominance(r: dict) -> str:
    """Eq. 2 (``minsubdt_jax.subdominance.min_subdominance``, the cell's beta) of each scalar run's mean costs against
    the demos' costs in the two metrics, and the demos' own, each against the others (leave-one-out): what the scalar
    token asks for, read in the two metrics the front is drawn in."""
    from minsubdt_jax.subdominance import min_subdominance

    demos = np.asarray(r["demo_costs"], np.float32)
    runs = np.array([np.mean(v["costs"], 0) for v in r["scalar"].values()], np.float32)
    own = np.asarray(min_subdominance(runs, demos, r["beta"]).value)
    line = (f"Eq. 2 against the demos in these two costs (beta {r['beta']}; lower: fewer demos beat it): "
            + ", ".join(f"`{k}` {v:.3f} (costs {c[0]:.3f}, {c[1]:.3f})" for k, v, c in zip(r["scalar"], own, runs)))
    if len(demos) < 2:
        return line + "."
    d = np.asarray(min_subdominance(demos, demos, r["beta"], leave_one_out=True).value)
    return line + f"; the demos' own, each against the others, {d.min():.3f}-{d.max():.3f} (median {np.median(d):.3f})."


def recordings(r: dict) -> str:
    """The scalar runs trained on another recording of the cell's recipe than the sweeps' (a machine of another
    instruction set records another file: docs/FIDELITY.md), by name and content hash; ``""`` if none."""
    other = {k: v["dataset_sha256"] for k, v in r.get("scalar", {}).items()
             if v.get("dataset_sha256", r.get("dataset_sha256")) != r.get("dataset_sha256")}
    return "" if not other else (
        "Trained on another recording of the same recipe (the target sweeps': " + r["dataset_sha256"][:12]
        + "): " + ", ".join(f"`{k}` ({v[:12]})" for k, v in other.items()) + ".")


def beyond_demos(method: str, means, d) -> str:
    """The targets whose rollouts spend less in a metric than every demo, ``means [targets, 2]`` their mean costs
    and ``d [n, 2]`` the demos': how many, and their mean cost in the other metric."""
    out = []
    for k in range(2):
        below = means[:, k] < d[:, k].min()
        if below.any():
            out.append(f"{below.sum()} of {len(means)} targets below every demo's {PAIR[k]} cost ({d[:, k].min():.3f}; "
                       f"theirs {means[below, k].mean():.3f}, at {PAIR[1 - k]} cost {means[below, 1 - k].mean():.3f})")
    return f"`{method}`: " + "; ".join(out) + "." if out else ""


def reach(pts: dict) -> str:
    """Where each set of points lies in metric space, ``pts`` the figure's ``{label: [n, 2]}`` (the demos' episodes,
    the scalar runs' and each target's rollout means): min-max per metric, and the demos' medians."""
    ranges = "; ".join(f"{k} {lo[0]:.3f}-{hi[0]:.3f}, {lo[1]:.3f}-{hi[1]:.3f}"
                       for k, p in pts.items() for lo, hi in [(np.min(p, 0), np.max(p, 0))])
    med = np.median(pts["demos"], 0)
    return (f"Costs reached, min-max over the points ({', '.join(PAIR)}): {ranges}; "
            f"the demos' medians {med[0]:.3f}, {med[1]:.3f}.")


def demos_trade_off(d) -> str:
    """What the data offers the targets, ``d [n, 2]`` the demos' costs: how the two costs go together, and how
    fast the tenth of the demos that spends least in the second metric is (what a frugal token asks for)."""
    from minsubdt_jax.costs import spearman

    tenth = np.argsort(d[:, 1], kind="stable")[:max(len(d) // 10, 1)]
    return (f"The demos' two costs: Spearman {spearman(d[:, 0], d[:, 1]):+.2f}; the tenth that spends least "
            f"{PAIR[1]} ({PAIR[1]} cost {d[tenth, 1].mean():.3f}) has {PAIR[0]} cost {d[tenth, 0].mean():.3f} "
            f"(all demos {d[:, 0].min():.3f}-{d[:, 0].max():.3f}).")


def under_way(r: dict) -> str:
    """The line of a cell whose file is ``partial`` (``front.run`` saves it as each part lands): what it holds, no
    numbers (a part of a sweep is not a front)."""
    sweeps = ", ".join(f"{m} {len(v)}" + " targets" * (i == 0) for i, (m, v) in enumerate(r.get("sweeps", {}).items()))
    scalar = ", ".join(k.removeprefix("minsubdt-") for k in r.get("scalar", {})) or "none"
    return (f"{r['cell']}: under way, not a result yet ({sweeps or 'no targets'}, scalar runs {scalar}); "
            "`bash experiments/queue.sh front` resumes it")


def report(a) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = sorted(f for f in os.listdir(RESULTS) if f.endswith(".json")) if os.path.isdir(RESULTS) else []
    if not files:
        raise SystemExit(f"no results under {RESULTS}: run `python experiments/front.py run` first")
    lines = ["# Fronts in metric space (issue 55)", "", "Generated by `python experiments/front.py report` from "
             "`experiments/results/front/*.json`. Costs are lower-is-better, in [0, 1]; the hypervolume is the area "
             f"the points dominate up to (1, 1) in ({', '.join(PAIR)}), computed by moocore. Spearman: over the "
             "target grid, between the target in a metric and the achieved cost in it (mean over seeds; +1: the "
             "target steers that metric perfectly); *other target held*: the same within each row of the grid that "
             "shares the other metric's target, mean over those rows and the seeds (a metric that steers only where "
             "the other's target allows it scores low over the whole grid and high here). The demos' points are "
             "single episodes; a method's point is the mean of one target's rollouts (3 seeds x its episodes), so the "
             "demos' front holds the spread of single episodes and the methods' fronts do not: compare the fronts' "
             "shapes in the figure as well as the numbers.", ""]
    cells = []
    for f in files:
        with open(os.path.join(RESULTS, f)) as fh:
            cells.append(json.load(fh))
    under = [under_way(r) for r in cells if r.get("partial")]
    lines += under + [""] * bool(under)
    cells = [r for r in cells if not r.get("partial")]
    fig, axes = plt.subplots(1, max(len(cells), 1), figsize=(6 * max(len(cells), 1), 5), squeeze=False)
    for ax, r in zip(axes[0], cells):
        text, pts = cell_report(r)
        lines += text
        for (label, p), style in zip(pts.items(), ("o", "s", "^", "v")):
            ax.scatter(p[:, 0], p[:, 1], s=8 if label == "demos" else 30, marker=style, alpha=0.35 if label ==
                       "demos" else 0.9, label=label)
        ax.set(xlabel=f"{PAIR[0]} cost", ylabel=f"{PAIR[1]} cost", title=r["cell"])
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, os.path.join(HERE, "results", "front.png"), dpi=110)
    lines += ["![the demos and the rollout means](front.png)", ""]
    with atomic_open(os.path.join(HERE, "results", "front.md")) as f:
        f.write("\n".join(lines))
    print("\n".join(lines))
