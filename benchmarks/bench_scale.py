"""Scale-out step times: 1 vs 2 devices, 1 vs 2 processes, ``--seeds 3`` in one program vs three runs.

    python benchmarks/bench_scale.py [--presets cpu paper] [--rounds 2] [--json benchmarks/results/scale.json]
    python benchmarks/bench_scale.py --platform cuda --configs "1 device" "3 seeds"   # on a 1-GPU machine

Each configuration runs in a fresh worker process (``--worker``) that times the training chunk exactly as
``python -m minsubdt_jax.train`` runs it (``init_seed_states``, the vmapped ``make_train_chunk`` on a
``make_mesh`` mesh, on a synthetic 64-trajectory dataset): the median seconds per step over ``--repeats``
chunks of ``--steps`` steps, after a compile. Configurations:

- ``1 device``: one process, one device (the default run);
- ``1 device, plain step``: the same without the seed axis (``make_train_chunk(seed_axis=False)``), to show
  what the uniform seed axis costs;
- ``2 devices``: one process, ``XLA_FLAGS=--xla_force_host_platform_device_count=2``, batch split in two;
- ``2 processes``: two workers on localhost joined by ``jax.distributed`` (gloo), one device each;
- ``3 seeds``: ``--seeds 3`` on one device; three single-seed runs one after another take 3 x ``1 device``.

The configurations of one round run one after another, and rounds repeat the whole set, so that every
configuration sees this (noisy) machine in more than one state. The speed-up columns are same-round ratios.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import socket
import statistics
import subprocess
import sys
from minsubdt_jax.atomic import atomic_open

CONFIGS = {  # name -> (devices per process, processes, seeds, seed axis)
    "1 device": (1, 1, 1, True),
    "1 device, plain step": (1, 1, 1, False),
    "2 devices": (2, 1, 1, True),
    "2 processes": (1, 2, 1, True),
    "3 seeds": (1, 1, 3, True),
}


def worker(preset: str, seeds: int, devices: int, steps: int, repeats: int, seed_axis: bool) -> dict:
    import jax

    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data import sampler_data
    from minsubdt_jax.parallel import make_mesh, replicate
    from minsubdt_jax.agents.base import init_seed_states, init_state, make_optimizer, make_train_chunk
    from minsubdt_jax.agents.dt.agent import make_dt_agent

    cfg = dataclasses.replace(PRESETS[preset], chunk_steps=steps, eval_every=0)
    from bench_train_step import synthetic_dataset, time_chunk

    ds = synthetic_dataset()
    obs, act, T = ds.obs_dim, ds.act_dim, ds.max_len
    mean, std = ds.state_stats()
    data = sampler_data(ds, ds.rewards, mean, std)
    agent, tx = make_dt_agent(cfg, obs, act, T), make_optimizer(cfg)
    state = init_seed_states(agent, tx, range(seeds)) if seed_axis else init_state(agent, tx, jax.random.PRNGKey(0))
    mesh = make_mesh(devices, cfg.batch_size)
    state, data = replicate((state, data), mesh)
    chunk = make_train_chunk(agent, tx, cfg.batch_size, steps, mesh, seed_axis=seed_axis)
    state, losses, compile_s, times = time_chunk(chunk, state, data, repeats)
    times = [t / steps for t in times]
    return {"ms_per_step": 1e3 * statistics.median(times), "compile_s": compile_s, "mesh_devices": mesh.size,
            "processes": jax.process_count(), "seeds": seeds, "batch_size": cfg.batch_size}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def run_config(name: str, preset: str, steps: int, repeats: int, platform: str = "cpu") -> dict:
    devices, processes, seeds, seed_axis = CONFIGS[name]
    env = dict(os.environ, JAX_PLATFORMS=platform)
    if platform == "cpu":  # forced host devices; on a GPU the devices are real, one per GPU
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}" if devices > 1 else ""
    cmd = [sys.executable, __file__, "--worker", "--presets", preset, "--seeds", str(seeds), "--devices",
           str(devices), "--steps", str(steps), "--repeats", str(repeats)] + ([] if seed_axis else ["--plain-step"])
    if processes > 1:
        port = _free_port()
        cmds = [cmd + ["--num-processes", str(processes), "--process-id", str(i), "--coordinator-address",
                       f"localhost:{port}"] for i in range(processes)]
    else:
        cmds = [cmd]
    procs = [subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for c in cmds]
    outs = [p.communicate(timeout=1200) for p in procs]
    for p, (o, e) in zip(procs, outs):
        if p.returncode:
            raise RuntimeError(f"{name}: worker failed\n{e[-3000:]}")
    return json.loads(outs[0][0].strip().splitlines()[-1])  # process 0's timing


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--presets", nargs="+", default=["cpu"])
    p.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--steps", type=int, default=0, help="steps per timed chunk (default: 50 cpu, 10 paper)")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--platform", default="cpu", choices=["cpu", "cuda"],
                   help="cuda: real GPUs ('2 devices' needs 2 of them; '2 processes' is CPU only)")
    p.add_argument("--json")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--seeds", type=int, default=1, help=argparse.SUPPRESS)
    p.add_argument("--devices", type=int, default=1, help=argparse.SUPPRESS)
    p.add_argument("--plain-step", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--num-processes", type=int, default=1, help=argparse.SUPPRESS)
    p.add_argument("--process-id", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--coordinator-address", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.worker:
        from minsubdt_jax.parallel import init_distributed

        init_distributed(a.coordinator_address, a.num_processes, a.process_id)
        print(json.dumps(worker(a.presets[0], a.seeds, a.devices, a.steps, a.repeats, not a.plain_step)))
        return
    if a.platform != "cpu" and "2 processes" in a.configs:
        p.error("'2 processes' runs two CPU workers on localhost; leave it out of --configs with --platform cuda")
    import jax

    out = {"machine": {"cpu_count": os.cpu_count(), "jax": jax.__version__, "platform": a.platform}, "rounds": []}
    for r in range(a.rounds):
        for preset in a.presets:
            steps = a.steps or (50 if preset != "paper" else 10)
            row = {"round": r, "preset": preset, "steps": steps}
            for name in a.configs:
                row[name] = run_config(name, preset, steps, a.repeats, a.platform)
                print(f"round {r} {preset:5s} {name:22s} {row[name]['ms_per_step']:8.1f} ms/step "
                      f"(compile {row[name]['compile_s']:.1f} s)", flush=True)
            out["rounds"].append(row)
    print("\n| preset | round | " + " | ".join(a.configs) + " | 2 devices speed-up | 2 processes speed-up | "
          "3 seeds vs 3 runs |")
    print("|---" * (len(a.configs) + 5) + "|")
    for row in out["rounds"]:
        ms = {n: row[n]["ms_per_step"] for n in a.configs}
        one = ms.get("1 device")
        ratio = lambda n, k=1: f"{k * one / ms[n]:.2f}x" if one and n in ms else "-"  # noqa: E731
        print(f"| {row['preset']} | {row['round']} | " + " | ".join(f"{v:.1f} ms" for v in ms.values())
              + f" | {ratio('2 devices')} | {ratio('2 processes')} | {ratio('3 seeds', 3)} |")
    if a.json:
        with atomic_open(a.json) as f:
            json.dump(out, f, indent=2)


if __name__ == "__main__":
    main()
