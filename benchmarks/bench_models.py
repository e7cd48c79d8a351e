"""Models in one program: training steps/s and TFLOP/s of M vmapped DT models, by matmul precision (issue 23).

    python benchmarks/bench_models.py --preset cpu --models 1 3 6 --precisions f32 bf16        # here (CPU)
    python benchmarks/bench_models.py --preset paper --models 12 36 108 --precisions f32 bf16 \
        --json benchmarks/results/models_gpu.json                                               # on a GPU

The chunk is the one ``python -m minsubdt_jax.train --method a,b --seeds S`` (or a whole env, ``--dataset a,b,c``)
scans: ``init_seed_states`` and the vmapped ``make_train_chunk`` over M models, each with its own return tokens,
on a synthetic dataset of 64 walker-sized 1000-step episodes. Per (M, precision): the median seconds per step
over ``--repeats`` chunks of ``--steps`` steps after a compile, the model-steps/s (M / that), and TFLOP/s from
XLA's own FLOP count of the compiled chunk (``cost_analysis()``, which counts the scanned step once: FLOPs per
step, all M models). Each configuration runs in this one process,
one after another; on this noisy CPU read the ratios of one run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
from minsubdt_jax.atomic import atomic_open


def bench(preset: str, models: int, precision: str, steps: int, repeats: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from minsubdt_jax.agents.base import init_seed_states, make_optimizer, make_train_chunk
    from minsubdt_jax.agents.dt.agent import make_dt_agent
    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data import sampler_data
    from minsubdt_jax.program import PER_MODEL_FIELDS

    from bench_train_step import synthetic_dataset, time_chunk

    cfg = dataclasses.replace(PRESETS[preset], chunk_steps=steps, eval_every=0, precision=precision)
    ds = synthetic_dataset()
    obs, act, T = ds.obs_dim, ds.act_dim, ds.max_len
    mean, std = ds.state_stats()
    data = sampler_data(ds, ds.rewards, mean, std)
    per_model = PER_MODEL_FIELDS  # what program.stack_models stacks for models on one dataset
    data = data.replace(**{k: jnp.stack([getattr(data, k) * (1 + 0.01 * i) for i in range(models)]) for k in per_model})
    axis = jax.tree.map(lambda _: None, data).replace(**{k: 0 for k in per_model})
    agent, tx = make_dt_agent(cfg, obs, act, T), make_optimizer(cfg)
    state = init_seed_states(agent, tx, range(models))
    chunk = make_train_chunk(agent, tx, cfg.batch_size, steps, seed_axis=True, data_axis=axis)
    t0 = time.perf_counter()
    compiled = chunk.lower(state, data).compile()
    compile_s = time.perf_counter() - t0
    cost = compiled.cost_analysis()
    flops = (cost[0] if isinstance(cost, list) else cost or {}).get("flops")
    state, losses, first_s, times = time_chunk(compiled, state, data, repeats)
    chunk_s = statistics.median(times)
    return {"preset": preset, "models": models, "precision": precision, "ms_per_step": 1e3 * chunk_s / steps,
            "model_steps_per_s": models * steps / chunk_s, "steps_per_s": steps / chunk_s,
            "gflop_per_step": flops / 1e9 if flops else None,
            "tflop_per_s": (flops * steps / chunk_s / 1e12) if flops else None, "compile_s": compile_s + first_s,
            "device": jax.devices()[0].device_kind, "backend": jax.default_backend(), "batch_size": cfg.batch_size,
            "finite_loss": bool(np.isfinite(np.asarray(losses)).all())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--preset", default="cpu", choices=["smoke", "cpu", "paper"])
    p.add_argument("--models", nargs="+", type=int, default=[1, 3, 6])
    p.add_argument("--precisions", nargs="+", default=["f32", "bf16"], choices=["f32", "tf32", "bf16"])
    p.add_argument("--steps", type=int, default=20, help="steps per timed chunk")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    rows = []
    for m in a.models:
        for prec in a.precisions:
            rows.append(bench(a.preset, m, prec, a.steps, a.repeats))
            r = rows[-1]
            tf = f"{r['tflop_per_s']:.3f}" if r["tflop_per_s"] is not None else "n/a"
            print(f"{a.preset} {m:4d} models {prec:5s}: {r['ms_per_step']:8.1f} ms/step, {r['model_steps_per_s']:8.1f} "
                  f"model-steps/s, {tf} TFLOP/s (compile + first chunk {r['compile_s']:.1f} s)", flush=True)
    if a.json:
        with atomic_open(a.json) as f:
            json.dump(rows, f, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
