"""Time jitted min_subdominance (exact, optax) and pairwise_subdominance against a per-row numpy loop.

    python benchmarks/bench_subdominance.py                         # N = M = 2000, K = 2, leave-one-out
    python benchmarks/bench_subdominance.py --sizes 100 1000 2000 10000 100000 --ks 1 2 4 --json out.json

``method="optax"`` (500 Adam steps on log alpha) is timed like exact, and its largest relative error against
exact over all rows is reported. The numpy reference is the straightforward exact solution: for each row and feature, sort the differences
to the demos and evaluate g at every breakpoint with suffix sums (O(M log M) per row). Compile time (first
call) is reported apart from run time (median of repeats after it). Rows with N > --numpy-max skip numpy.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import jax
import numpy as np

from minsubdt_jax.subdominance import min_subdominance, pairwise_subdominance
from minsubdt_jax.atomic import atomic_open


def numpy_min_subdominance(F, G, beta=1.0, leave_one_out=False):
    """[N] exact eq. 2 by a per-row loop in numpy."""
    N, K = F.shape
    out = np.zeros(N)
    for i in range(N):
        total = 0.0
        for k in range(K):
            d = F[i, k] - G[:, k]
            if leave_one_out:
                d = np.delete(d, i)
            d = np.sort(d)
            m = len(d)
            suffix = np.concatenate([np.cumsum(d[::-1])[::-1][1:], [0.0]])  # sum of d_i for i > j
            count = m - 1 - np.arange(m)
            neg = d < 0
            a = beta / -d[neg]
            vals = (a * suffix[neg] + beta * count[neg]) / m
            total += min(beta, vals.min()) if vals.size else beta
        out[i] = total
    return out


def timed(fn, repeats):
    """(median run seconds, compile seconds = first call minus a run, result)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t0)
    run = statistics.median(runs)
    return run, max(first - run, 0.0), out


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[2000])
    p.add_argument("--ks", type=int, nargs="+", default=[2])
    p.add_argument("--loo", choices=["yes", "no", "both"], default="yes")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--optax-max", type=int, default=10000, help="largest N for method='optax'")
    p.add_argument("--optax-repeats", type=int, default=3, help="timed optax calls after the first")
    p.add_argument("--pairwise-max", type=int, default=10000, help="largest N for pairwise_subdominance")
    p.add_argument("--numpy-max", type=int, default=2000, help="largest N for the numpy loop")
    p.add_argument("--json", default=None)
    a = p.parse_args()
    loos = {"yes": [True], "no": [False], "both": [False, True]}[a.loo]
    rows = []
    print(f"# {platform.processor() or platform.machine()}, {jax.device_count()} {jax.default_backend()} device(s), "
          f"jax {jax.__version__}")
    print(f"{'N=M':>7} {'K':>2} {'loo':>4} | {'exact s':>9} {'(compile)':>9} | {'optax s':>9} {'(compile)':>9} | "
          f"{'pairwise s':>10} | {'numpy s':>9} | {'numpy/exact':>11} {'optax rel err':>13}")
    for n in a.sizes:
        for K in a.ks:
            for loo in loos:
                rng = np.random.default_rng(0)
                G = rng.normal(size=(n, K)).astype(np.float32)
                F = G if loo else rng.normal(size=(n, K)).astype(np.float32)
                r = {"N": n, "M": n, "K": K, "leave_one_out": loo}
                r["exact_s"], r["exact_compile_s"], exact = timed(
                    lambda: min_subdominance(F, G, leave_one_out=loo).value, a.repeats)
                exact = np.asarray(exact)
                if n <= a.optax_max:
                    r["optax_s"], r["optax_compile_s"], opt = timed(
                        lambda: min_subdominance(F, G, leave_one_out=loo, method="optax").value, a.optax_repeats)
                    opt = np.asarray(opt, np.float64)
                    r["optax_max_abs_err"] = float(np.abs(opt - exact).max())
                    r["optax_max_rel_err"] = float((np.abs(opt - exact) / (exact + 1e-6)).max())
                if n <= a.pairwise_max:
                    alpha = np.ones(K, np.float32)
                    r["pairwise_s"], r["pairwise_compile_s"], _ = timed(lambda: pairwise_subdominance(F, G, alpha, 1.0),
                                                                     a.repeats)
                if n <= a.numpy_max:
                    t0 = time.perf_counter()
                    ref = numpy_min_subdominance(F.astype(np.float64), G.astype(np.float64), 1.0, loo)
                    r["numpy_s"] = time.perf_counter() - t0
                    r["numpy_over_exact"] = r["numpy_s"] / r["exact_s"]
                    r["exact_max_abs_err_vs_numpy"] = float(np.abs(ref - exact).max())
                rows.append(r)
                f = lambda key, w=9: f"{r[key]:{w}.4f}" if key in r else f"{'-':>{w}}"  # noqa: E731
                print(f"{n:>7} {K:>2} {str(loo)[0]:>4} | {f('exact_s')} {f('exact_compile_s')} | {f('optax_s')} "
                      f"{f('optax_compile_s')} | {f('pairwise_s', 10)} | {f('numpy_s')} | "
                      f"{r.get('numpy_over_exact', float('nan')):>11.0f} {r.get('optax_max_rel_err', float('nan')):>13.2e}",
                      flush=True)
    if a.json:
        with atomic_open(a.json) as fh:
            json.dump({"machine": platform.processor() or platform.machine(), "jax": jax.__version__, "rows": rows},
                      fh, indent=2)


if __name__ == "__main__":
    main()
