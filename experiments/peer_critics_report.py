"""The report of ``experiments/peer_critics.py``: ``experiments/results/peer_critics.md`` from its result files (one per
agent and cell, each side's seeds; step times), with Welch's verdict on ours against d3rlpy's. Run as ``python
experiments/peer_critics.py report``."""

from __future__ import annotations

import json
import os

import numpy as np

from minsubdt_jax.atomic import write_atomic

HERE = os.path.dirname(os.path.abspath(__file__))  # experiments/
RESULTS = os.path.join(HERE, "results", "peer_critics")


def _stats(xs) -> str:
    return f"{np.mean(xs):.1f} ± {np.std(xs):.1f}" if xs else "–"


def report_rows(results: list[dict]) -> list[str]:
    """One table row per result file: the seeds of both sides, their means ± std, and the difference's verdict."""
    from welch import welch  # beside this file

    rows = []
    for r in results:
        peer = [r["peer"][s]["normalized_score_mean"] for s in sorted(r["peer"], key=int)]
        ours = [s["normalized_score_mean"] for s in r.get("ours", {}).get("seeds", [])]
        verdict = "under way"
        if len(peer) >= 2 and len(ours) >= 2:
            w = welch(*({"mean": np.mean(x), "std": np.std(x), "n_seeds": len(x)} for x in (ours, peer)))
            p = "" if w["p"] is None else f" (p {w['p']:.2f})"
            verdict = f"{w['diff']:+.1f} ± {w['se']:.1f}: {'level' if abs(w['diff']) <= 2 * w['se'] else 'differ'}{p}"
        fmt = lambda xs: ", ".join(f"{x:.1f}" for x in xs) or "–"  # noqa: E731
        rows.append(f"| {r['agent']} | {r['env']} {r['dataset']} ({r['sha256']}) | {r['steps']:,} | {fmt(peer)} | "
                    f"{fmt(ours)} | {_stats(peer)} | {_stats(ours)} | {verdict} |")
    return rows


def curve_rows(results: list[dict]) -> list[str]:
    """Score points of both sides at the same steps (mean over seeds), for the results that kept them."""
    rows = []
    for r in results:
        peer = [r["peer"][s].get("curve", []) for s in sorted(r["peer"], key=int)]
        ours = r.get("ours", {}).get("curve", [])
        steps = sorted({p["step"] for c in peer for p in c} | {p["step"] for p in ours})
        for step in steps:
            pv = [p["normalized_score_mean"] for c in peer for p in c if p["step"] == step]
            ov = [x for p in ours if p["step"] == step for x in np.atleast_1d(p["normalized_score_mean"])]
            rows.append(f"| {r['agent']} | {r['env']} {r['dataset']} | {step:,} | {_stats(pv)} ({len(pv)}) | "
                        f"{_stats(ov)} ({len(ov)}) |")
    return rows


def report(a=None) -> str:
    """``results/peer_critics.md`` from the result files of ``RESULTS``."""
    names = sorted(os.listdir(RESULTS)) if os.path.isdir(RESULTS) else []
    results = [json.load(open(os.path.join(RESULTS, n))) for n in names if not n.startswith("time-")]
    text = ("# Our critic agents beside d3rlpy's on the same file\n\n"
            "Normalised scores (our references), the mean over 100 episodes per seed in our gymnasium env, each side's "
            "parameter average (EMA) at the last step; mean ± std over seeds; ours − d3rlpy's ± the standard error of "
            "the difference (Welch), *level* within 2 SE. Settings matched and what d3rlpy cannot match: the docstring "
            "of `experiments/peer_critics.py`. Commands: each file's `command` (`.venv-peer/bin/python "
            "experiments/peer_critics.py run --agent A --env E --dataset D`), then `python experiments/peer_critics.py "
            "report`.\n\n| agent | file | steps | d3rlpy (per seed) | ours (per seed) | d3rlpy | ours | ours − d3rlpy |"
            "\n|---|---|---|---|---|---|---|---|\n" + "\n".join(report_rows(results)) + "\n")
    curves = curve_rows(results)
    if curves:
        text += ("\n## Score points during training (`--eval-every`; mean ± std over seeds (count), 30 episodes each)"
                 "\n\n| agent | cell | step | d3rlpy | ours |\n|---|---|---|---|---|\n" + "\n".join(curves) + "\n")
    for n in (n for n in names if n.startswith("time-")):
        t = json.load(open(os.path.join(RESULTS, n)))
        text += (f"\nTraining step of {t['agent']} on this {t['cores']}-core CPU (one model, {t['steps']} steps, "
                 f"`peer_critics.py time --agent {t['agent']}`, torch threads {t['torch_threads']}): d3rlpy "
                 f"{1e3 * t['d3rlpy_s_per_step']:.1f} ms, ours {1e3 * t['ours_s_per_step']:.1f} ms: "
                 f"{t['ratio']:.2f}x in our favour.\n")
    write_atomic(os.path.join(HERE, "results", "peer_critics.md"), text)
    print(text)
    return text
