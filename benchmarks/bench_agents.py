"""Train-step speed of every agent at its own settings, measured in one run: the DT at the `cpu` and `paper`
presets (batch 64 windows), BC with an MLP (batch 64), and the critic agents IQL, TD3+BC, CQL, BRAC-v and BEAR at
their references' settings (batch 256 transitions; IQL and TD3+BC 2 x 256 networks, CQL 3 x 256 with 10 + 10 + 10
sampled actions, BRAC-v 300 x 300 critics and 200 x 200 policies with 4 KL samples, BEAR a 750 x 750 VAE and 10
target samples, AWR 128 x 64 nets). BRAC-v and BEAR are timed in their main stage (after the pretraining or warm-up);
AWR by its 1200-step iteration (the lambda-returns of the 64k stored states, 200 value and 1000 policy steps).

    python benchmarks/bench_agents.py [--agents dt-cpu dt-paper bc-mlp iql td3bc cql brac bear] [--steps 50]
                                      [--repeats 5] [--precisions f32 bf16] [--json benchmarks/results/agents.json]

``--precisions``: each agent (but BC with an MLP) at each matmul precision, ``<agent>@<precision>`` in the table
(bf16: bfloat16 matmuls from float32 parameters; on a CPU without bf16 units it is no faster, the GPU's case).

Each agent's jitted ``lax.scan`` chunk of ``--steps`` steps (the one training runs: sampling, forward, backward,
updates; one seed) on a synthetic walker-shaped dataset (64 episodes x 1000 steps, 17-d states, 6-d actions).
The agents' chunks are timed in turn, ``--repeats`` rounds, so every agent sees the same machine state; the table
gives the median ms/step and each agent's time relative to the DT at the `cpu` preset in the same round.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import time

import jax
import numpy as np

from bench_train_step import synthetic_dataset  # beside this file (a script's folder is on its path)

from minsubdt_jax.agents import batch_size_of, make_agent
from minsubdt_jax.agents.base import init_state, make_train_chunk, optimizer_for
from minsubdt_jax.config import PRESETS
from minsubdt_jax.data import sampler_data
from minsubdt_jax.atomic import atomic_open

# name -> (agent, preset whose fields it takes)
AGENTS = {"dt-cpu": ("dt", "cpu"), "dt-paper": ("dt", "paper"), "bc-mlp": ("mlp", "cpu"), "iql": ("iql", "cpu"),
          "td3bc": ("td3bc", "cpu"), "cql": ("cql", "cpu"), "brac": ("brac", "cpu"), "bear": ("bear", "cpu"),
          "awr": ("awr", "cpu")}
AWR_ITERATION = 1200  # AWR's chunk is one iteration (lambda-returns of the dataset, value and policy steps)


def make_chunk(name: str, steps: int, data, precision: str = "f32"):
    agent_name, preset = AGENTS[name]
    steps = AWR_ITERATION if agent_name == "awr" else steps
    cfg = dataclasses.replace(PRESETS[preset], chunk_steps=steps, eval_every=0, steps=1_000_000, precision=precision)
    agent = make_agent(agent_name, cfg, 17, 6, 1000)
    tx = optimizer_for(agent, cfg)
    batch = batch_size_of(agent_name, cfg)
    state = init_state(agent, tx, jax.random.PRNGKey(0))
    state = state.replace(step=state.step + 10**6 // 2)  # past any pretraining stage or warm-up
    chunk = make_train_chunk(agent, tx, batch, steps)
    t0 = time.perf_counter()
    state, losses = chunk(state, data)
    jax.block_until_ready(losses)
    holder = {"state": state}

    def run():
        holder["state"], losses = chunk(holder["state"], data)
        jax.block_until_ready(losses)

    return run, time.perf_counter() - t0, batch, steps


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--agents", nargs="+", default=list(AGENTS), choices=list(AGENTS))
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--precisions", nargs="+", default=["f32"], choices=["f32", "tf32", "bf16"])
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    ds = synthetic_dataset()
    mean, std = ds.state_stats()
    data = sampler_data(ds, ds.rewards, mean, std)
    names = [n if p == "f32" else f"{n}@{p}" for p in a.precisions for n in a.agents
             if p == "f32" or AGENTS[n][0] != "mlp"]
    runs = {n: make_chunk(n.split("@")[0], a.steps, data, (n.split("@") + ["f32"])[1]) for n in names}
    times = {n: [] for n in names}
    for _ in range(a.repeats):
        for n, (run, _, _, steps) in runs.items():
            t0 = time.perf_counter()
            run()
            times[n].append((time.perf_counter() - t0) / steps)
    ref = times.get("dt-cpu")
    rows = []
    for n in names:
        ms = 1e3 * statistics.median(times[n])
        rel = statistics.median(t / r for t, r in zip(times[n], ref)) if ref else float("nan")
        rows.append({"agent": n, "batch": runs[n][2], "ms_per_step": ms, "steps_per_s": 1e3 / ms,
                     "relative_to_dt_cpu": rel, "compile_s": runs[n][1]})
    print("| agent | batch | ms/step | steps/s | vs DT cpu (same round) | compile + first chunk, s |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['agent']} | {r['batch']} | {r['ms_per_step']:.2f} | {r['steps_per_s']:.0f} | "
              f"{r['relative_to_dt_cpu']:.2f} | {r['compile_s']:.1f} |")
    if a.json:
        with atomic_open(a.json) as f:
            json.dump({"rows": rows, "steps": a.steps, "repeats": a.repeats, "backend": jax.default_backend(),
                       "device": jax.devices()[0].device_kind, "cpus": os.cpu_count(), "jax": jax.__version__,
                       "numpy": np.__version__}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
