"""Score curves: several methods x seeds trained as one program with periodic evaluation, and how noisy a score is.

    python experiments/curves.py run --env walker --dataset medium --model cpu --steps 20000 --eval-every 2000
    python experiments/curves.py run --env hopper --dataset medium-replay --model paper --context 10
    python experiments/curves.py run --env walker --model paper --steps 10000 --warmup 500 --lr-schedule cosine
    python experiments/curves.py report                  # every curve under experiments/results/curves/
    python experiments/curves.py ties                    # demos sharing the surrogate return -K beta: results/ties.md
    python experiments/curves.py ties --cells walker:medium --cost-sets default x_velocity,energy   # per cost set

``run`` trains ``--methods`` (default MinSubDT and DT) x ``--seeds`` models of one ``--model`` size (``cpu``: the
cpu preset's 64 x 2 DT, lr 3e-4, warm-up 500; ``paper``: the DT paper's 128 x 3, lr 1e-4, warm-up 10k) in one
program (``python -m minsubdt_jax.train --method a,b --seeds S``), evaluating every model on ``--episodes``
episodes every ``--eval-every`` steps. It resumes from the run directory's last checkpoint when started again
(``runs/curves/<name>``), and writes ``experiments/results/curves/<name>.{json,png}`` when done: per evaluation
step and model, the mean and the standard deviation over episodes of the normalised score. A curve whose file is
there (and not a ``snapshot``'s partial one) is not run again, on any machine.

The noise report separates the two sources of spread of a method's score at one step: the standard error of one
seed's mean over its episodes (std / sqrt(episodes)), and the spread between seeds (the std of the seed means),
and gives the seeds and episodes that a 3-point change needs to stand out (2 standard errors of the mean over
seeds <= 3 points).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys

import numpy as np

from curves_report import RESULTS, plot, report  # beside this file (a script's folder is on its path)
from minsubdt_jax.atomic import atomic_open

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_METHODS = "minsubdt,dt"
DEFAULT_STEPS = 20_000
MODELS = {"cpu": "cpu", "paper": "paper"}  # model size -> the preset whose DT and optimiser it takes


def name_of(a) -> str:
    extra = ("" if a.lr_schedule == "constant" else f"-{a.lr_schedule}") + (f"-ema{a.ema:g}" if a.ema else "")
    extra += f"-costs-{a.costs.replace(',', '+')}" if a.costs else ""
    extra += "" if a.methods == DEFAULT_METHODS else f"-{a.methods.replace(',', '+')}"
    extra += f"-seed{a.seed}" if a.seed else ""
    extra += f"-wu{a.warmup}" if a.warmup is not None else ""
    extra += f"-alpha{a.brac_alpha:g}" if a.brac_alpha is not None else ""
    extra += f"-pre{a.pretrain_steps}" if a.pretrain_steps is not None else ""
    extra += f"-lr{a.lr:g}" if a.lr is not None else ""
    extra += f"-{a.steps}steps" if a.steps != DEFAULT_STEPS else ""  # a cosine run's schedule ends at its steps
    extra += f"-{a.tag}" if a.tag else ""
    return f"{a.env}-{a.dataset}-{a.model}-k{a.context}{extra}"


def run(a) -> dict:
    from minsubdt_jax.agents import preset_config
    from minsubdt_jax.config import validate
    from minsubdt_jax.train import train

    out = os.path.join(a.runs_root, name_of(a))
    given = {"warmup_steps": a.warmup, "brac_alpha": a.brac_alpha, "pretrain_steps": a.pretrain_steps,
             "learning_rate": a.lr}  # flags left unset keep the model's preset
    cfg = dataclasses.replace(preset_config(MODELS[a.model], a.methods), env=a.env, dataset=a.dataset, seed=a.seed,
                              seeds=a.seeds, steps=a.steps, eval_every=a.eval_every, eval_episodes_periodic=a.episodes,
                              eval_episodes=a.episodes, context_len=a.context, chunk_steps=a.chunk_steps,
                              physics=a.physics, lr_schedule=a.lr_schedule, ema_decay=a.ema, costs=a.costs,
                              out=out, **{k: v for k, v in given.items() if v is not None})
    validate(cfg)  # a bad setting is an error before a finished curve is skipped
    done = os.path.join(RESULTS, name_of(a) + ".json")
    if os.path.exists(done):
        with open(done) as f:
            curve = json.load(f)
        if not curve.get("partial"):  # its run directory may be on another machine: nothing to train again
            print(f"{done}: complete; nothing to do", flush=True)
            return curve
    res = train(cfg, resume=os.path.exists(os.path.join(out, "config.json")))
    curve = collect(out, res)
    os.makedirs(RESULTS, exist_ok=True)
    with atomic_open(os.path.join(RESULTS, name_of(a) + ".json")) as f:
        json.dump(curve, f, indent=1)
    plot(curve, os.path.join(RESULTS, name_of(a) + ".png"))
    return curve


def snapshot(a) -> dict:
    """The curve so far of a run that has not finished (cut, or still going): from its run directory's
    ``config.json``, ``dataset.json`` and ``metrics.jsonl``; marked ``partial`` with the command that resumes it."""
    from minsubdt_jax.data import resolve_dataset
    from minsubdt_jax.references import normalized_score
    from minsubdt_jax.agents.dt.networks import DT_REVISION
    from minsubdt_jax.runresults import platform

    out = os.path.join(a.runs_root, name_of(a))
    with open(os.path.join(out, "config.json")) as f:
        cfg = json.load(f)
    with open(os.path.join(out, "dataset.json")) as f:
        ds = json.load(f)
    with open(os.path.join(out, "metrics.jsonl")) as f:
        first = next(r for r in map(json.loads, filter(str.strip, f)) if "eval_normalized_score" in r)
    data = resolve_dataset(cfg["env"], cfg["dataset"], verbose=False, physics=cfg["physics"])
    if data.sha256 != ds["sha256"]:
        raise SystemExit(f"{data.path} is not the run's data (sha256 {ds['sha256'][:12]})")
    ds["normalized_score_mean"] = float(normalized_score(cfg["env"], data.data.returns, ds["dynamics"]).mean())
    res = {"config": cfg, "dataset": ds, "physics": {"physics": cfg["physics"], "dynamics": ds["dynamics"]},
           "platform": platform(), "dt_revision": DT_REVISION,  # the run directory is this machine's, and this code's
           "models": [{"method": m, "seed": s} for m, s in zip(first["eval_method"], first["eval_seed"])]}
    curve = collect(out, res)
    curve.update(partial=True, command=" ".join(["python experiments/curves.py run", *sys.argv[2:]]))
    with atomic_open(os.path.join(RESULTS, name_of(a) + ".json")) as f:
        json.dump(curve, f, indent=1)
    plot(curve, os.path.join(RESULTS, name_of(a) + ".png"))
    return curve


def collect(run_dir: str, res: dict) -> dict:
    """The evaluations of ``metrics.jsonl``: ``{"steps": [...], "models": [{"method", "seed", "mean": [...],
    "std": [...]}]}`` plus what the run was (config, dataset, physics)."""
    with open(os.path.join(run_dir, "metrics.jsonl")) as f:
        records = [json.loads(line) for line in f if line.strip()]
    evals = [r for r in records if "eval_normalized_score" in r]
    models = [{"method": m["method"], "seed": m["seed"], "mean": [], "std": []} for m in res["models"]]
    if any("eval_raw_normalized_score" in r for r in evals):  # --ema: periodic evaluations scored the raw ones too
        models += [{"method": m["method"] + " (raw params)", "seed": m["seed"], "mean": [], "std": []}
                   for m in res["models"]]
    n = len(res["models"])
    for r in evals:
        for i, m in enumerate(models):
            prefix = "eval_" if i < n else "eval_raw_"
            if prefix + "normalized_score" not in r:  # the final evaluation scores the average only
                m["mean"].append(float("nan"))
                m["std"].append(float("nan"))
                continue
            m["mean"].append(r[prefix + "normalized_score"][i % n])
            m["std"].append(r[prefix + "normalized_score_std"][i % n])
    cfg = res["config"]
    command = " ".join(["python experiments/curves.py run", *sys.argv[2:]]) if sys.argv[1:2] == ["run"] else None
    if command is not None and os.path.exists(os.path.join(RESULTS, os.path.basename(run_dir) + ".json")):
        with open(os.path.join(RESULTS, os.path.basename(run_dir) + ".json")) as f:  # resumed: the first command
            command = json.load(f).get("command") or command
    return {"command": command,
            "config": cfg, "dataset": {k: res["dataset"][k] for k in ("path", "sha256", "episodes", "transitions",
                                                                        "normalized_score_mean")},
            "physics": res.get("physics"), "references": res.get("references"), "platform": res.get("platform"),
            "dt_revision": res.get("dt_revision", 1),
            "train_seconds": round(sum(r.get("chunk_seconds", 0.0) for r in records), 1),
            "steps": [r["step"] for r in evals], "episodes": [r["eval_episodes"] for r in evals], "models": models}


CELLS = "walker:medium,hopper:medium-replay,halfcheetah:medium-expert"


def ties(cells: str = CELLS, cost_sets=(None,), beta: float = 1.0, alpha_max=None) -> list[dict]:
    """The demos whose min-subdominance (eq. 2, leave-one-out) is exactly K beta, per ``env:dataset`` cell and cost
    set (None: the env's engineered costs): with alpha >= 0 minimised, a demo no better than the others' mean on a
    feature gets alpha = 0 there (a cap ``alpha_max`` leaves it there), so every demo at or below the mean on all
    features shares one surrogate return, whatever its true return. Also: the share of the top-quartile-return demos
    that are tied, and how well -min-subdominance ranks the true return over all demos and over the untied ones.
    Writes ``experiments/results/ties.md``."""
    from minsubdt_jax.costs import engineered_costs, spearman
    from minsubdt_jax.data import resolve_dataset
    from minsubdt_jax.subdominance import min_subdominance

    rows = []
    for env, ds in (c.split(":") for c in cells.split(",")):
        f = resolve_dataset(env, ds, verbose=False)
        d = f.data
        top = d.returns >= np.quantile(d.returns, 0.75)
        for costs in cost_sets:
            F = np.asarray(engineered_costs(env, d.observations, d.lengths, 1000, terminated=d.terminals,
                                            actions=d.actions, costs=costs))
            ms = np.asarray(min_subdominance(F, F, beta, leave_one_out=True, alpha_max=alpha_max).value)
            tie = np.isclose(ms, F.shape[1] * beta)
            rows.append({"env": env, "dataset": ds, "file": os.path.basename(f.path), "sha256": f.sha256,
                         "costs": costs or "default", "episodes": d.num_trajectories, "K": F.shape[1],
                         "tied_share": float(tie.mean()), "tied_return_min": float(d.returns[tie].min()),
                         "tied_return_max": float(d.returns[tie].max()), "return_median": float(np.median(d.returns)),
                         "top_quartile_tied": float(tie[top].mean()), "spearman_all": spearman(-ms, d.returns),
                         "spearman_untied": spearman(-ms[~tie], d.returns[~tie])})
            r = rows[-1]
            print(f"{env} {ds} ({r['file']}, {r['episodes']} episodes, costs {r['costs']}, K={r['K']}): "
                  f"{100 * r['tied_share']:.1f} % of the demos at min-subdominance K*beta, true returns "
                  f"{r['tied_return_min']:.1f} .. {r['tied_return_max']:.1f} (median of all {r['return_median']:.1f}); "
                  f"{100 * r['top_quartile_tied']:.1f} % of the top quartile tied; Spearman(-ms, return) "
                  f"{r['spearman_all']:.3f}, among the untied {r['spearman_untied']:.3f}", flush=True)
    lines = ["# The tie at min-subdominance K beta", "",
             f"`{' '.join(['python experiments/curves.py', *sys.argv[1:]])}` (beta {beta:g}, leave-one-out): per cell "
             "and cost set, the share of demos tied at exactly K beta, their true returns against the median demo's, "
             "the share of the top-quartile-return demos among them, and Spearman(-min-subdominance, return).", "",
             "| cell | data (sha256) | costs | K | tied | tied returns | median return | top quartile tied | "
             "Spearman all | Spearman untied |", "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['env']} {r['dataset']} | {r['episodes']} episodes ({r['sha256'][:12]}) | {r['costs']} | "
              f"{r['K']} | {100 * r['tied_share']:.1f} % | {r['tied_return_min']:.0f} .. {r['tied_return_max']:.0f} | "
              f"{r['return_median']:.0f} | {100 * r['top_quartile_tied']:.1f} % | {r['spearman_all']:.3f} | "
              f"{r['spearman_untied']:.3f} |" for r in rows]
    with atomic_open(os.path.join(HERE, "results", "ties.md")) as fh:
        fh.write("\n".join(lines) + "\n")
    return rows


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=["run", "snapshot", "report", "ties", "name"],
                   help="snapshot: commit the curve so far of an unfinished run (same flags as its run); name: print "
                   "the run's name (its runs/curves/ directory and results file)")
    p.add_argument("--env", default="walker")
    p.add_argument("--dataset", default="medium")
    p.add_argument("--methods", default=DEFAULT_METHODS)
    p.add_argument("--model", default="cpu", choices=sorted(MODELS))
    p.add_argument("--context", type=int, default=20)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--seed", type=int, default=0, help="the first seed (more seeds of a curve: its own file)")
    p.add_argument("--steps", type=int, default=DEFAULT_STEPS)
    p.add_argument("--eval-every", type=int, default=2000)
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--chunk-steps", type=int, default=500)
    p.add_argument("--lr-schedule", default="constant", choices=["constant", "cosine"])
    p.add_argument("--costs", default=None, help="cost metrics (minsubdt_jax.costs), comma-separated")
    p.add_argument("--ema", type=float, default=0.0, help="EMA decay of the parameters (0: off); the raw "
                   "parameters are scored beside the average")
    p.add_argument("--physics", default="auto", choices=["auto", "mjx", "mujoco"])
    p.add_argument("--warmup", type=int, default=None, help="warm-up steps of the rate (default: the model's "
                   "preset's: cpu 500, paper 10k)")
    p.add_argument("--lr", type=float, default=None, help="peak learning rate (default: the model's preset's: cpu "
                   "3e-4, paper 1e-4)")
    p.add_argument("--brac-alpha", type=float, default=None, help="BRAC-v's alpha (default: the config's 0.1)")
    p.add_argument("--pretrain-steps", type=int, default=None, help="BRAC-v's behaviour-policy steps, BEAR's "
                   "warm-up (default: the config's, a fraction of --steps)")
    p.add_argument("--runs-root", default="runs/curves")
    p.add_argument("--tag", default="", help="appended to the curve's name: a run on another machine's recording "
                   "of the data (e.g. h200) keeps its own file")
    p.add_argument("--cells", default=CELLS, help="ties: env:dataset,...")
    p.add_argument("--cost-sets", nargs="+", default=["default"], help="ties: cost sets (comma-separated metrics; "
                   "default: the env's engineered costs)")
    p.add_argument("--alpha-max", type=float, default=None, help="ties: a cap on alpha")
    return p


def main(argv=None) -> int:
    a = build_parser().parse_args(argv)
    if a.action == "name":
        print(name_of(a))
        return 0
    if a.action == "ties":
        ties(a.cells, [None if c == "default" else c for c in a.cost_sets], alpha_max=a.alpha_max)
        return 0
    if a.action == "run":
        try:
            run(a)
        except ValueError as e:  # a bad setting (or data): one line, nothing trained
            build_parser().error(str(e))
    if a.action == "snapshot":
        snapshot(a)
    print(report())
    return 0


if __name__ == "__main__":
    sys.exit(main())
