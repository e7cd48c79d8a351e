"""How close ``min_subdominance(method="optax")`` comes to ``method="exact"`` on hard random instances.

    python benchmarks/optax_accuracy.py                 # 200 instances per leave-one-out setting
    python benchmarks/optax_accuracy.py --json benchmarks/results/optax_accuracy.json

Instances (N = M = 64, K = 2, one compile per setting): values on a grid minus gaps of 1e-3..1e-1 grid units,
at scales 0.01..100, so rows tie with demos, dominate every demo, or beat a demo by a sliver (the optimal alpha
``beta / gap`` reaches 1e3 / scale); leave-one-out scores the demo set itself; a quarter capped by alpha_max.
Prints the largest and the 99th-percentile relative error per row, ``|optax - exact| / (exact + 1e-6 beta)``.
The script calls only the public API, so it runs against older versions too (``PYTHONPATH=old/src``).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from minsubdt_jax.subdominance import min_subdominance
from minsubdt_jax.atomic import atomic_open


def instance(rng, loo: bool, n: int = 64, k: int = 2):
    scale = 10.0 ** rng.integers(-2, 3)
    gaps = np.array([0.0, 0.0, 1e-3, 1e-2, 1e-1])

    def values():
        return ((rng.integers(-4, 5, (n, k)) / 2 - gaps[rng.integers(0, 5, (n, k))]) * scale).astype(np.float32)

    F = values()
    G = F.copy() if loo else values()
    beta = float(rng.choice([0.5, 1.0, 2.0]))
    alpha_max = None if rng.random() < 0.75 else 30.0 / scale
    return F, G, beta, alpha_max


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--instances", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    a = p.parse_args()
    out = {}
    for loo in (False, True):
        rng = np.random.default_rng(a.seed)
        errs, t0 = [], time.perf_counter()
        for _ in range(a.instances):
            F, G, beta, amax = instance(rng, loo)
            ex = np.asarray(min_subdominance(F, G, beta, alpha_max=amax, leave_one_out=loo).value, np.float64)
            op = np.asarray(min_subdominance(F, G, beta, alpha_max=amax, leave_one_out=loo, method="optax").value,
                            np.float64)
            errs.append(np.abs(op - ex) / (ex + 1e-6 * beta))
        e = np.concatenate(errs)
        out["leave_one_out" if loo else "plain"] = {
            "rows": int(e.size), "max_rel_err": float(e.max()), "p99_rel_err": float(np.quantile(e, 0.99)),
            "rows_over_1e-3": int((e > 1e-3).sum()), "seconds": time.perf_counter() - t0}
        r = out["leave_one_out" if loo else "plain"]
        print(f"leave_one_out={loo}: {r['rows']} rows, max rel err {r['max_rel_err']:.2e}, p99 {r['p99_rel_err']:.2e}, "
              f"rows over 1e-3: {r['rows_over_1e-3']} ({r['seconds']:.0f} s)", flush=True)
    if a.json:
        with atomic_open(a.json) as f:
            json.dump({"instances": a.instances, "seed": a.seed, **out}, f, indent=2)


if __name__ == "__main__":
    main()
