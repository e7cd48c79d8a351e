"""DT train step speed at the `paper` and `cpu` presets, against this machine's dense matmul speed.

    python benchmarks/bench_train_step.py [--presets paper cpu] [--steps 20] [--json out.json]

FLOPs per step are XLA's own count (``compiled.cost_analysis()['flops']``) for one jitted train step
(sampling, forward, backward, AdamW update); the step time is the median over ``--steps``-step ``lax.scan``
chunks, exactly as training runs them. The matmul reference is a jitted f32 [2048, 2048] @ [2048, 2048].
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from minsubdt_jax.config import PRESETS
from minsubdt_jax.data import Trajectories, sampler_data
from minsubdt_jax.train import init_state, make_model, make_optimizer, make_train_chunk, make_train_step


def matmul_gflops(n=2048, repeats=10):
    a = jnp.asarray(np.random.default_rng(0).normal(size=(n, n)), jnp.float32)
    f = jax.jit(lambda x: x @ x)
    f(a).block_until_ready()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f(a).block_until_ready()
        ts.append(time.perf_counter() - t0)
    return 2 * n ** 3 / statistics.median(ts) / 1e9


def synthetic_dataset(n=64, T=1000, obs=17, act=6):
    rng = np.random.default_rng(0)
    return Trajectories(rng.normal(size=(n, T, obs)).astype(np.float32),
                        rng.uniform(-1, 1, (n, T, act)).astype(np.float32), rng.normal(size=(n, T)).astype(np.float32),
                        np.full(n, T, np.int32), np.zeros(n, bool))


def bench(preset: str, steps: int, repeats: int) -> dict:
    cfg = dataclasses.replace(PRESETS[preset], chunk_steps=steps)
    ds = synthetic_dataset()
    mean, std = ds.state_stats()
    data = sampler_data(ds, ds.rewards, mean, std)
    model = make_model(cfg, ds.act_dim, 1000)
    tx = make_optimizer(cfg)
    state = init_state(model, tx, cfg, ds.obs_dim)

    # XLA's FLOP count of the very step function that the timed chunk scans
    flops = jax.jit(make_train_step(model, tx, cfg)).lower(state, data).compile().cost_analysis()["flops"]
    chunk = make_train_chunk(model, tx, cfg, steps)
    t0 = time.perf_counter()
    state, _ = chunk(state, data)
    jax.block_until_ready(state)
    compile_s = time.perf_counter() - t0
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state, losses = chunk(state, data)
        jax.block_until_ready(losses)
        ts.append((time.perf_counter() - t0) / steps)
    step_s = statistics.median(ts)
    return {"preset": preset, "context_len": cfg.context_len, "embed_dim": cfg.embed_dim, "n_layers": cfg.n_layers,
            "batch_size": cfg.batch_size, "ms_per_step": 1e3 * step_s, "gflop_per_step": flops / 1e9,
            "gflops": flops / step_s / 1e9, "first_chunk_s_incl_compile": compile_s}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--presets", nargs="+", default=["paper", "cpu"], choices=list(PRESETS))
    p.add_argument("--steps", type=int, default=20, help="steps per timed lax.scan chunk")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", default=None)
    a = p.parse_args()
    ref = matmul_gflops()
    print(f"# jax {jax.__version__}, {jax.default_backend()}; dense f32 matmul 2048^3: {ref:.1f} GFLOP/s")
    print(f"{'preset':>7} {'K':>3} {'d':>4} {'L':>2} {'B':>4} | {'ms/step':>8} {'GFLOP/step':>10} {'GFLOP/s':>8} "
          f"{'of matmul':>9}")
    rows = []
    for preset in a.presets:
        r = bench(preset, a.steps, a.repeats)
        r["matmul_gflops"] = ref
        r["fraction_of_matmul"] = r["gflops"] / ref
        rows.append(r)
        print(f"{preset:>7} {r['context_len']:>3} {r['embed_dim']:>4} {r['n_layers']:>2} {r['batch_size']:>4} | "
              f"{r['ms_per_step']:>8.1f} {r['gflop_per_step']:>10.2f} {r['gflops']:>8.1f} {r['fraction_of_matmul']:>9.0%}",
              flush=True)
    ref2 = matmul_gflops()
    print(f"# matmul again after the runs: {ref2:.1f} GFLOP/s")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"jax": jax.__version__, "matmul_gflops": [ref, ref2], "rows": rows}, fh, indent=2)


if __name__ == "__main__":
    main()
