"""Table 1's report: the markdown of ``experiments/results/table1.md`` and the cost-feature plots, from the
aggregate that ``experiments/table1.py`` computes. The seed's published numbers live here too."""

from __future__ import annotations

import os

import numpy as np

from minsubdt_jax.agents import AGENTS
from minsubdt_jax.config import PRESETS
from minsubdt_jax.methods import METHODS as ALL_METHODS

from welch import welch  # experiments/

ENVS = ("halfcheetah", "hopper", "walker")
DATASETS = ("medium-expert", "medium", "medium-replay")
METHODS = ("minsubdt", "minsubdt-learned", "dt", "bc")  # the seed's MinSubDT (engg., learned), DT and BC columns
# the critic agents' columns, shown once run: the seed's (in its order, PUBLISHED_BASELINES below), then every other
# method of an agent that trains on transitions (AgentInfo.transitions), MinSubDT's surrogate reward under each among
# them, in minsubdt_jax.methods' order
SEED_BASELINES = ("cql", "bear", "brac-v", "awr")
CRITIC_METHODS = SEED_BASELINES + tuple(m for m, x in ALL_METHODS.items()
                                        if AGENTS[x.agent].transitions and m not in SEED_BASELINES)
COLUMNS = METHODS + CRITIC_METHODS
MINSUBDT_COLUMNS = ("minsubdt", "minsubdt-learned")  # the columns the report holds against DT's
METHOD_NAMES = {m: ALL_METHODS[m].label for m in COLUMNS}

# Seed Table 1 (gym/D4RL v2 datasets, normalised by D4RL's references): not comparable one to one with ours.
PUBLISHED = {
    (d, e): dict(zip(METHODS, v)) for (d, e), v in {
        ("medium-expert", "halfcheetah"): (89.5, 86.8, 87.0, 59.9),
        ("medium-expert", "hopper"): (110.7, 110.8, 107.6, 79.6),
        ("medium-expert", "walker"): (108.1, 108.5, 108.1, 36.6),
        ("medium", "halfcheetah"): (41.3, 40.9, 42.6, 43.1),
        ("medium", "hopper"): (56.8, 55.8, 67.6, 63.9),
        ("medium", "walker"): (70.4, 74.9, 74.0, 77.3),
        ("medium-replay", "halfcheetah"): (32.3, 31.8, 36.6, 4.3),
        ("medium-replay", "hopper"): (40.5, 37.1, 82.7, 27.6),
        ("medium-replay", "walker"): (37.1, 36.0, 66.6, 36.9),
    }.items()
}

# The seed's other columns (the DT paper's Table 2: CQL from the CQL paper, BEAR, BRAC-v and AWR from the D4RL
# paper; gym MuJoCo, D4RL v0 data): CQL, BEAR, BRAC-v, AWR per (dataset, env)
PUBLISHED_BASELINES = {
    (d, e): dict(zip(SEED_BASELINES, v)) for (d, e), v in {
        ("medium-expert", "halfcheetah"): (62.4, 53.4, 41.9, 52.7),
        ("medium-expert", "hopper"): (111.0, 96.3, 0.8, 27.1),
        ("medium-expert", "walker"): (98.7, 40.1, 81.6, 53.8),
        ("medium", "halfcheetah"): (44.4, 41.7, 46.3, 37.4),
        ("medium", "hopper"): (58.0, 52.1, 31.1, 35.9),
        ("medium", "walker"): (79.2, 59.1, 81.1, 17.4),
        ("medium-replay", "halfcheetah"): (46.2, 38.6, 47.7, 40.3),
        ("medium-replay", "hopper"): (48.6, 33.7, 0.6, 28.4),
        ("medium-replay", "walker"): (26.7, 19.2, 0.9, 15.5),
    }.items()
}


def columns(table: dict) -> tuple:
    """The DT-family columns, then each critic method that has a result in ``table``."""
    present = {m for row in table.values() for m in row}
    return METHODS + tuple(m for m in CRITIC_METHODS if m in present)


def _cell(entry) -> str:
    """``mean ± std (seeds)``; one seed has no spread to show, so it says so instead of "± 0.0"."""
    if entry is None:
        return "–"
    if entry["n_seeds"] == 1:
        return f"{entry['mean']:.1f} (1 seed)"
    return f"{entry['mean']:.1f} ± {entry['std']:.1f} ({entry['n_seeds']})"


def versus_dt(table: dict, methods=MINSUBDT_COLUMNS) -> dict:
    """Per cell (``"dataset/env"``) and MinSubDT column of ``table`` (:func:`table1.aggregate`'s, population std over
    n seeds): ``{"diff": mean - DT's mean, "se", "df", "p", "verdict"}``, Welch's test over the seeds
    (:func:`welch.welch`). The verdict is "behind" or "ahead" where |diff| > 2 se, "level" where it is not, and "–"
    (no verdict; se, df and p None) with fewer than 2 seeds on either side. Cells without a DT result or without the
    column are left out."""
    out = {}
    for key, row in table.items():
        dt = row.get("dt")
        for m in (m for m in methods if dt is not None and m in row):
            if min(row[m]["n_seeds"], dt["n_seeds"]) < 2:
                w = {"diff": row[m]["mean"] - dt["mean"], "se": None, "df": None, "p": None, "verdict": "–"}
            else:
                w = welch(row[m], dt)
                w["verdict"] = "level" if abs(w["diff"]) <= 2 * w["se"] else ("behind" if w["diff"] < 0 else "ahead")
            out.setdefault(key, {})[m] = w
    return out


def _versus_lines(vs: dict) -> list[str]:
    """The report's section on where MinSubDT is behind DT, from :func:`versus_dt`."""
    methods = MINSUBDT_COLUMNS
    lines = ["", "## Where MinSubDT is behind DT, and by how much", "",
             "Each MinSubDT column's seed mean minus DT's, ± the standard error of that difference (Welch, over the "
             "seeds), and the verdict: *behind* or *ahead* where the difference exceeds two standard errors, "
             "*level* where it does not. With 2 or 3 seeds that is a weak test both ways: a level cell may still "
             "differ, and 2 SE is not a 5 % test at so few degrees of freedom, so Welch's two-sided p (its "
             "Welch-Satterthwaite degrees of freedom) is given beside each verdict.", "",
             "| dataset | env | " + " | ".join(f"{METHOD_NAMES[m]} − DT" for m in methods) + " |", "|---|---|" + "---|" * len(methods)]

    def fmt(v):
        if v is None:
            return "–"
        p = "" if v["p"] is None else f" (p {v['p']:.2f})"  # None: fewer than 2 seeds, or no spread in either
        return f"{v['diff']:+.1f}" + ("" if v["se"] is None else f" ± {v['se']:.1f}") + f": {v['verdict']}{p}"

    lines += [f"| {d} | {e} | " + " | ".join(fmt(vs.get(f"{d}/{e}", {}).get(m)) for m in methods) + " |"
              for d in DATASETS for e in ENVS]
    for m in methods:
        got = [(k, v[m]) for k, v in vs.items() if m in v and v[m]["verdict"] != "–"]
        if got:
            behind = [f"{k.split('/')[1]} {k.split('/')[0]} ({v['diff']:+.1f})" for k, v in got
                      if v["verdict"] == "behind"]
            lines.append(f"\n{METHOD_NAMES[m]}: behind DT in {len(behind)} of {len(got)} cells with ≥ 2 seeds each"
                         + (": " + ", ".join(behind) if behind else "") + f"; mean difference "
                         f"{np.mean([v['diff'] for _, v in got]):+.1f} over those cells.")
    return lines


def _critic_settings(preset: str, methods) -> list[str]:
    """A line per critic agent with a column: the setting its own curve chose at ``preset`` (``AgentInfo.presets``)."""
    own = {a: info.presets[preset] for a, info in AGENTS.items() if info.presets.get(preset)}
    agents = sorted({ALL_METHODS[m].agent for m in methods if m in CRITIC_METHODS} & set(own))
    return [f"Critic columns train at their own `{preset}` setting, chosen by their own 3-seed curves "
            "(`minsubdt_jax.agents.AGENTS`' presets, [docs/convergence.md](../../docs/convergence.md)): "
            + "; ".join(f"{a}: {own[a]['steps']:,} steps at its reference's rates"
                        + (f", evaluated with an EMA {own[a]['ema_decay']} of its parameters" if own[a].get("ema_decay")
                           else "") for a in agents) + ".", ""
            ] if agents else []


def _recordings(entries: list[dict]) -> dict:
    """A cell's distinct recordings, ``{(file, sha256): dataset's own score}``, from its ``data_files`` entries."""
    return {(x["file"], x["sha256"]): x["dataset_score"] for x in entries}


def data_files(rows: list[dict]) -> tuple[dict, dict]:
    """Which recording(s) of each cell's dataset its runs used, ``{"d/e": [{file, sha256, cost_features, physics,
    dynamics, dataset_score, methods}]}`` (the file name holds the recipe version), and the dataset's own score per
    cell: the mean over its distinct recordings (file, hash), each counted once however many runs used it."""
    files = {}
    for row in rows:
        ds, ph = row["r"]["dataset"], row["r"].get("physics") or {}
        files.setdefault(f"{row['dataset']}/{row['env']}", {}).setdefault(
            (os.path.basename(ds.get("path", "?")), ds.get("sha256", "not recorded")[:12], "+".join(ds["costs_mean"]),
             ph.get("physics", "not recorded"), ph.get("dynamics", "not recorded"), ds["normalized_score_mean"]),
            {}).setdefault(row["method"], set()).add(row["seed"])
    files = {k: [{"file": f, "sha256": h, "cost_features": c, "physics": p, "dynamics": d, "dataset_score": s,
                  "methods": [m for m in COLUMNS if m in ms], "seeds": {m: sorted(ms[m]) for m in COLUMNS if m in ms}}
                 for (f, h, c, p, d, s), ms in sorted(v.items())]
             for k, v in files.items()}
    demo = {k: float(np.mean(list(_recordings(v).values()))) for k, v in files.items()}
    return files, demo


def _used_by(method: str, entry: dict, entries: list[dict]) -> str:
    """A method's name in a recording's "used by", with the seeds that used it where its seeds span recordings."""
    seeds = entry["seeds"][method] if sum(method in x["methods"] for x in entries) > 1 else None
    return METHOD_NAMES[method] + (f" [seed{'s' * (len(seeds) > 1)} {', '.join(map(str, seeds))}]" if seeds else "")


def markdown(out: dict) -> str:
    """``experiments/results/table1.md`` from :func:`table1.summarise`'s ``out``: the table and its sections."""
    methods = columns(out["table"])

    def cells(fmt):  # one markdown row per dataset x env: "| d | e | " + fmt(d, e, table row) + " |"
        return [f"| {d} | {e} | {fmt(d, e, out['table'].get(f'{d}/{e}', {}))} |" for d in DATASETS for e in ENVS]

    lines = (_header(out, methods) + _scores(out, methods, cells) + _versus_lines(out["versus_dt"] if "versus_dt" in out
             else versus_dt(out["table"])) + _better_than_demonstrated(methods, cells) + _cost_agreement(out, cells)
             + _data(out) + _curves(out) + _published())
    return "\n".join(lines) + "\n"


def _header(out: dict, methods) -> list[str]:
    lines = [f"# Table 1 on our recorded datasets (preset `{out['preset']}`)", "",
             "Normalised score (100 = committed SAC expert, 0 = uniform random, both measured in the brax-dynamics "
             "envs), mean ± std over the "
             f"training seeds present (their count in brackets), {out.get('eval_episodes', '?')} evaluation "
             f"episodes per seed at the `{out['preset']}` preset. '–' = not run yet. Regenerate: "
             f"`python experiments/table1.py --preset {out['preset']}` (runs what is missing, then aggregates).", ""]
    if out["preset"] == "study":
        return lines + [
            f"The `study` preset: the `cpu` model at a peak rate of {PRESETS['study'].learning_rate:g} with a "
            f"cosine decay over {PRESETS['study'].steps // 1000}k steps and an average of the parameters, "
            "chosen from score curves on this CPU. [docs/convergence.md](../../docs/convergence.md) says "
            "which cells' curves have flattened at it (and which have not) and how it differs from the "
            "paper's configuration; the DT-family table at its earlier rate, 3e-4, is there too (results in "
            "`table1/study-lr3e-4/`). See *Data* below for the dataset files and cost features these runs "
            "used.", "", *_critic_settings(out["preset"], methods)]
    if out["preset"] == "paper":
        return lines
    return lines + [f"**Not a result**: the `{out['preset']}` preset is a stage of training, not a converged score "
                    "(README, *What the presets are for*); the `study` and `paper` presets are. See *Data* below "
                    "for the dataset files and cost features these runs used.", ""]


def _scores(out: dict, methods, cells) -> list[str]:
    """The table of scores, its averages, and the critic agents still without a column."""
    cols = [METHOD_NAMES[m] for m in methods]
    lines = ["| dataset | env | dataset's own | " + " | ".join(cols) + " |", "|---|---|---|" + "---|" * len(cols)]

    def own(d, e):
        v, n = out["dataset_score"].get(f"{d}/{e}"), len(_recordings(out.get("data_files", {}).get(f"{d}/{e}", [])))
        return "–" if v is None else f"{v:.1f}" + (f" (mean of {n} recordings)" if n > 1 else "")

    lines += cells(lambda d, e, row: own(d, e) + " | " + " | ".join(_cell(row.get(m)) for m in methods))
    for label, av in out["averages"].items():
        lines.append(f"| **average ({label})** | | | " + " | ".join(
            "–" if av.get(m, {}).get("mean") is None
            else f"{av[m]['mean']:.1f} ({av[m]['cells']}/{av[m]['of']} cells)" for m in methods) + " |")
    absent = [m for m in CRITIC_METHODS if not m.startswith("minsubdt-") and m not in methods]
    if absent:
        ready = [METHOD_NAMES[m] for m in absent if out["preset"] in AGENTS[ALL_METHODS[m].agent].presets]
        lines += ["", f"Critic agents without a result at `{out['preset']}` (every cell '–'): "
                  f"{', '.join(METHOD_NAMES[m] for m in absent)}. "
                  "One gets a column once its score curve flattens within ~10 CPU-minutes per model here (issue 25); "
                  "the others wait for a GPU. Their speeds and curves: [docs/critics.md](../../docs/critics.md)."
                  + (f" With a setting but no column yet: {', '.join(ready)}." if ready else "")]
    return lines


def _better_than_demonstrated(methods, cells) -> list[str]:
    cols = [METHOD_NAMES[m] for m in methods]
    return ["", "## Better than demonstrated?", "",
            "Share of evaluation rollouts that dominate the dataset's mean demo in the engineered cost features "
            "(none above it, one below), "
            "and the rollouts' min-subdominance (eq. 2, engineered features) against the demos (lower is "
            "better); mean over seeds.", "",
            "| dataset | env | " + " | ".join(cols) + " |", "|---|---|" + "---|" * len(cols)] + cells(
        lambda d, e, row: " | ".join("–" if m not in row else f"{row[m]['better_than_mean_demo_share']:.0%} / "
                                     f"{row[m]['rollout_min_subdominance']:.2f}" for m in methods))


def _cost_agreement(out: dict, cells) -> list[str]:
    def agreement(d, e, _):
        c = out["cost_rank_agreement"].get(f"{d}/{e}", {})
        eng, lr = c.get("engineered_spearman"), c.get("learned", [])
        sp = f"{np.mean([x['spearman'] for x in lr]):.3f} ({len(lr)})" if lr else "–"
        acc = f"{np.mean([x['heldout_pair_accuracy'] for x in lr]):.3f}" if lr else "–"
        return f"{'–' if eng is None else f'{eng:.3f}'} | {sp} | {acc}"

    return ["", "## Cost representations: do they rank the demos like the true return?", "",
            "Spearman correlation of −min-subdominance (eq. 2, leave-one-out over the dataset) with the true "
            "return, for the engineered features and for the learned ones (eq. 3; K' = 2, mean over seeds), "
            "and the learned costs' held-out preference accuracy (pairs among the 20 % of trajectories "
            "held out of training). Per feature, over all episodes and over those that never fell, for the "
            "designs considered: [cost_features.md](cost_features.md).", "",
            "| dataset | env | engineered: Spearman | learned: Spearman | learned: held-out pair accuracy |",
            "|---|---|---|---|---|"] + cells(agreement)


def _data(out: dict) -> list[str]:
    lines = ["", "## Data", "",
             "The dataset file(s) the runs of each cell used (the name holds the recording recipe; hash of the "
             "episodes, where the run recorded it) and their engineered cost features. A cell whose file is not "
             "today's `python -m minsubdt_jax.data` recording, or whose features are not today's "
             "`minsubdt_jax.costs`, was run on an earlier recipe.", "",
             "| dataset | env | file (sha256): cost features; evaluation physics, dynamics; dataset's own score; "
             "used by |", "|---|---|---|"]
    for d, e in ((d, e) for d in DATASETS for e in ENVS):
        xs = out.get("data_files", {}).get(f"{d}/{e}", [])
        lines.append(f"| {d} | {e} | " + "; ".join(
            f"{x['file']} ({x['sha256']}): {x['cost_features']}; {x['physics']}, {x['dynamics']}; dataset's own "
            f"{x['dataset_score']:.1f}; used by " + ", ".join(_used_by(m, x, xs) for m in x["methods"]) for x in xs)
            + " |")
    return lines


def _curves(out: dict) -> list[str]:
    lines = ["", "## Curves", "",
             "Score and loss against the gradient step of each cell's training runs (`python -m minsubdt_jax.plot`, "
             "drawn by `aggregate` from the `curve` each result file keeps, all methods and seeds of the cell, or "
             "else from the run directories on the machine that trained them), and the convergence curves of "
             "[curves.md](curves.md).", ""]
    lines += [f"- {d} {e}: ![curves]({png})" for key, png in sorted(out.get("curves", {}).items())
              for d, e in [key.split("/")]] or ["- none on the machine that aggregated"]
    lost = [k.replace("/", " ") for k in sorted(out.get("table", {})) if k not in out.get("curves", {})]
    if lost and out.get("curves"):
        lines += [f"- no figure: {', '.join(lost)} (trained on a machine that is gone, before result files kept "
                  "their curve; the final 100-episode evaluations above are complete)"]
    return lines


def _published() -> list[str]:
    lines = ["", "## Published (seed Table 1: gym MuJoCo, D4RL v2 data, D4RL normalisation)", "",
             "Not comparable one to one with the table above: other physics, other behaviour policies, other "
             "references, 100k training steps. For orientation only.", "",
             "| dataset | env | " + " | ".join(METHOD_NAMES[m] for m in METHODS) + " | CQL | BEAR | BRAC-v | AWR |",
             "|---|---|" + "---|" * (len(METHODS) + 4)]
    for (d, e), v in PUBLISHED.items():
        lines.append(f"| {d} | {e} | " + " | ".join(f"{x:.1f}" for x in [v[m] for m in METHODS]
                                                     + list(PUBLISHED_BASELINES[d, e].values())) + " |")
    return lines
