"""Are two training runs the same? Parameters (last checkpoint), losses and evaluation returns, compared exactly.

    python experiments/compare_runs.py RUN_A RUN_B            # exit 0 if identical, 1 if not

For reproducibility checks: one command run by two versions of the code (a refactor must not change results),
or on two machines (it will differ: XLA and the physics are not bit-stable across CPUs). Prints the largest
absolute difference of every compared quantity.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
from minsubdt_jax.rundir import per_model


def load(run: str) -> dict:
    import jax
    import orbax.checkpoint as ocp

    mngr = ocp.CheckpointManager(os.path.abspath(os.path.join(run, "checkpoints")))
    step = mngr.latest_step()
    params = [np.asarray(x) for x in jax.tree.leaves(mngr.restore(step)["params"])]
    with open(os.path.join(run, "metrics.jsonl")) as f:
        losses = [per_model(json.loads(ln), "loss") for ln in f if '"loss"' in ln]
    with open(os.path.join(run, "results.json")) as f:
        res = json.load(f)
    evals = per_model(res) or [res["eval"]]
    return {"step": step, "params": params, "losses": np.asarray(losses),
            "eval_returns": np.asarray([e["returns"] for e in evals]),
            "dataset": res["dataset"].get("sha256") or res["dataset"]["path"]}


def compare(a: dict, b: dict) -> dict:
    out = {"step": (a["step"], b["step"]), "same_dataset": a["dataset"] == b["dataset"]}
    shapes = [x.shape for x in a["params"]] == [x.shape for x in b["params"]]
    out["params_max_abs_diff"] = max(float(np.abs(x - y).max()) for x, y in zip(a["params"], b["params"])) \
        if shapes else float("inf")
    for key in ("losses", "eval_returns"):
        out[f"{key}_max_abs_diff"] = float(np.abs(a[key] - b[key]).max()) if a[key].shape == b[key].shape \
            else float("inf")
    out["identical"] = (out["step"][0] == out["step"][1] and all(
        out[k] == 0.0 for k in ("params_max_abs_diff", "losses_max_abs_diff", "eval_returns_max_abs_diff")))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_a")
    p.add_argument("run_b")
    a = p.parse_args(argv)
    for run in (a.run_a, a.run_b):
        if not os.path.isdir(os.path.join(run, "checkpoints")):
            p.error(f"{run}: not a run directory (no checkpoints)")
    out = compare(load(a.run_a), load(a.run_b))
    print(json.dumps(out, indent=1))
    return 0 if out["identical"] else 1


if __name__ == "__main__":
    sys.exit(main())
