"""DT train step speed at the `paper` and `cpu` presets, against this machine's dense matmul speed.

    python benchmarks/bench_train_step.py [--presets paper cpu] [--steps 20] [--json out.json]

FLOPs per step are XLA's own count (``compiled.cost_analysis()['flops']``) for one jitted train step
(sampling, forward, backward, AdamW update); the step time is the median over ``--steps``-step ``lax.scan``
chunks, exactly as training runs them (``--devices N``: data parallel over N local devices, e.g. with
``XLA_FLAGS=--xla_force_host_platform_device_count=2`` on a CPU). The matmul reference is a jitted f32
[2048, 2048] @ [2048, 2048].

What bounds the step: ``dots-only`` replays every ``dot_general`` of the step (read from its lowered
StableHLO: the same shapes and dimension numbers, fed by the loop carry so nothing is hoisted) in a scan of the
same length with nothing else. Its time is the step's floor if all non-matmul work were free, and its rate is
what this machine's matmul reaches at the step's (small) shapes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from minsubdt_jax.config import PRESETS
from minsubdt_jax.data import Trajectories, sampler_data
from minsubdt_jax.parallel import make_mesh, replicate
from minsubdt_jax.agents.base import init_state, make_optimizer, make_train_chunk, make_train_step
from minsubdt_jax.agents.dt.agent import make_dt_agent
from minsubdt_jax.atomic import atomic_open


def make_matmul(n=2048):
    """A timed f32 [n, n] @ [n, n]: returns ``gflops()`` measuring one call."""
    x = jnp.asarray(np.random.default_rng(0).normal(size=(n, n)), jnp.float32)
    f = jax.jit(lambda x: x @ x)
    f(x).block_until_ready()

    def gflops():
        t0 = time.perf_counter()
        f(x).block_until_ready()
        return 2 * n ** 3 / (time.perf_counter() - t0) / 1e9

    return gflops


def matmul_gflops(n=2048, repeats=10):
    """Median f32 matmul GFLOP/s over ``repeats`` calls."""
    g = make_matmul(n)
    return statistics.median(g() for _ in range(repeats))


_DOT = re.compile(r"stablehlo\.dot_general .*?(?:batching_dims = \[([\d, ]*)\] x \[([\d, ]*)\], )?"
                  r"contracting_dims = \[([\d, ]*)\] x \[([\d, ]*)\].*: \(tensor<([\dx]+)xf32>, "
                  r"tensor<([\dx]+)xf32>\)")


def step_dots(lowered_text: str) -> list:
    """``[(lhs_shape, rhs_shape, dimension_numbers)]`` of every f32 dot_general in a lowered step."""
    ints = lambda t: tuple(int(v) for v in t.replace(" ", "").split(",") if v)  # noqa: E731
    dots = []
    for m in _DOT.finditer(lowered_text):
        lb, rb, lc, rc, ls, rs = m.groups()
        dots.append((ints(ls.replace("x", ",")), ints(rs.replace("x", ",")),
                     ((ints(lc), ints(rc)), (ints(lb or ""), ints(rb or "")))))
    return dots


def make_dots_only(dots: list):
    """``(run, flops)``: ``run()`` calls one jit that computes only ``dots`` and returns all their outputs."""
    rng = np.random.default_rng(0)
    ops = [(jnp.asarray(rng.normal(size=ls), jnp.float32), jnp.asarray(rng.normal(size=rs), jnp.float32))
           for ls, rs, _ in dots]
    f = jax.jit(lambda ops: tuple(jax.lax.dot_general(a, b, dn) for (a, b), (_, _, dn) in zip(ops, dots)))
    # FLOP of a dot_general: 2 * batch * lhs-free * rhs-free * contracted = 2 |lhs| |rhs| / (batch * contracted)
    flops = sum(2 * np.prod(ls) * np.prod(rs) / (np.prod([ls[i] for i in lc]) * np.prod([ls[i] for i in lb]))
                for ls, rs, ((lc, _), (lb, _)) in dots)
    jax.block_until_ready(f(ops))
    return (lambda: jax.block_until_ready(f(ops))), float(flops)


def synthetic_dataset(n=64, T=1000, obs=17, act=6):
    rng = np.random.default_rng(0)
    return Trajectories(rng.normal(size=(n, T, obs)).astype(np.float32),
                        rng.uniform(-1, 1, (n, T, act)).astype(np.float32), rng.normal(size=(n, T)).astype(np.float32),
                        np.full(n, T, np.int32), np.zeros(n, bool))


def time_chunk(chunk, state, data, repeats: int):
    """Run ``chunk(state, data)`` once (compile + first run) and ``repeats`` more times; ``(state, losses,
    compile_s, [seconds of each timed chunk])``."""
    import jax

    t0 = time.perf_counter()
    state, losses = chunk(state, data)
    jax.block_until_ready(losses)
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state, losses = chunk(state, data)
        jax.block_until_ready(losses)
        times.append(time.perf_counter() - t0)
    return state, losses, compile_s, times


def timeit(fn, div=1):
    t0 = time.perf_counter()
    fn()
    return (time.perf_counter() - t0) / div


def bench(preset: str, steps: int, repeats: int, matmul, dropout: float | None = None, devices: int = 1) -> dict:
    """Time the preset's train chunk and its dots-only replay, interleaved with the matmul reference so that
    all three see the same machine state; ratios are medians of per-repeat ratios."""
    cfg = dataclasses.replace(PRESETS[preset], chunk_steps=steps, eval_every=0)
    if dropout is not None:
        cfg = dataclasses.replace(cfg, dropout=dropout)
    ds = synthetic_dataset()
    mean, std = ds.state_stats()
    data = sampler_data(ds, ds.rewards, mean, std)
    agent = make_dt_agent(cfg, ds.obs_dim, ds.act_dim, 1000)
    tx = make_optimizer(cfg)
    state = init_state(agent, tx, jax.random.PRNGKey(cfg.seed))

    # XLA's FLOP count of the very step function that the timed chunk scans, and its dots
    lowered = jax.jit(make_train_step(agent, tx, cfg.batch_size)).lower(state, data)
    flops = lowered.compile().cost_analysis()["flops"]
    dots = step_dots(lowered.as_text())
    dots_run, dot_flops = make_dots_only(dots)
    mesh = make_mesh(devices, cfg.batch_size)
    state, data = replicate((state, data), mesh)
    chunk = make_train_chunk(agent, tx, cfg.batch_size, steps, mesh)
    t0 = time.perf_counter()
    state, _ = chunk(state, data)
    jax.block_until_ready(state)
    compile_s = time.perf_counter() - t0

    def run_chunk():
        nonlocal state
        state, losses = chunk(state, data)
        jax.block_until_ready(losses)

    rows = []
    for _ in range(repeats):
        ref = matmul()
        step_s = timeit(run_chunk, steps)
        dots_s = min(timeit(dots_run) for _ in range(3))
        rows.append((ref, step_s, dots_s))
    ref, step_s, dots_s = (statistics.median(c) for c in zip(*rows))
    med = lambda f: statistics.median(f(*r) for r in rows)  # noqa: E731
    return {"preset": preset, "context_len": cfg.context_len, "embed_dim": cfg.embed_dim, "n_layers": cfg.n_layers,
            "batch_size": cfg.batch_size, "dropout": cfg.dropout, "devices": mesh.size, "ms_per_step": 1e3 * step_s,
            "gflop_per_step": flops / 1e9,
            "gflops": flops / step_s / 1e9, "matmul_gflops": ref,
            "fraction_of_matmul": med(lambda r, s, d: flops / s / 1e9 / r),
            "dots": len(dots), "dot_gflop_per_step": dot_flops / 1e9, "dots_only_ms": 1e3 * dots_s,
            "dots_only_gflops": dot_flops / dots_s / 1e9,
            "dots_only_fraction_of_matmul": med(lambda r, s, d: dot_flops / d / 1e9 / r),
            "dots_share_of_step": med(lambda r, s, d: d / s), "repeats": repeats,
            "first_chunk_s_incl_compile": compile_s}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--presets", nargs="+", default=["paper", "cpu"], choices=list(PRESETS))
    p.add_argument("--steps", type=int, default=20, help="steps per timed lax.scan chunk")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--dropout", type=float, default=None, help="override the presets' dropout (0: its cost)")
    p.add_argument("--devices", type=int, default=1, help="data parallel over this many local devices (0: all)")
    p.add_argument("--json", default=None)
    a = p.parse_args()
    matmul = make_matmul()
    print(f"# jax {jax.__version__}, {jax.default_backend()}; reference: dense f32 matmul 2048^3, timed between "
          f"the step timings")
    print(f"{'preset':>7} {'K':>3} {'d':>4} {'L':>2} {'B':>4} | {'ms/step':>8} {'GFLOP/step':>10} {'GFLOP/s':>8} "
          f"{'matmul':>7} {'of matmul':>9} | {'dots-only ms':>12} {'GFLOP/s':>8} {'of matmul':>9} {'of step':>7}")
    rows = []
    for preset in a.presets:
        r = bench(preset, a.steps, a.repeats, matmul, a.dropout, a.devices)
        rows.append(r)
        print(f"{preset:>7} {r['context_len']:>3} {r['embed_dim']:>4} {r['n_layers']:>2} {r['batch_size']:>4} | "
              f"{r['ms_per_step']:>8.1f} {r['gflop_per_step']:>10.2f} {r['gflops']:>8.1f} {r['matmul_gflops']:>7.0f} "
              f"{r['fraction_of_matmul']:>9.0%} | {r['dots_only_ms']:>12.1f} {r['dots_only_gflops']:>8.1f} "
              f"{r['dots_only_fraction_of_matmul']:>9.0%} {r['dots_share_of_step']:>7.0%}", flush=True)
    if a.json:
        with atomic_open(a.json) as fh:
            json.dump({"jax": jax.__version__, "rows": rows}, fh, indent=2)


if __name__ == "__main__":
    main()
