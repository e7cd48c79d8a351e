"""Env-steps/s of batched rollouts, per env x physics backend x policy, measured in one run.

    python benchmarks/bench_physics.py --json benchmarks/results/physics.json
    python benchmarks/bench_physics.py --envs walker --policies sac dt-paper --backends mujoco

Each row rolls out ``--episodes`` episodes with ``minsubdt_jax.envs.make_rollout`` (the program evaluation and
dataset recording run) and counts the env steps actually simulated; the first call (compile) is timed apart.

Policies:
- ``random``: uniform actions (the physics alone; hopper and walker fall within ~20-60 steps, so their batches
  shrink and the rate includes that);
- ``sac``: the committed SAC expert's stochastic actor (a 2x256 MLP), the policy datasets are recorded with;
- ``dt-cpu`` / ``dt-paper``: the DT rollout policy at that preset's size (random weights, K = 20 context, the
  forward pass the evaluation runs), whose action is added at 1e-6 scale to the SAC expert's: the DT's whole cost
  is paid on every step, and the episodes last as a trained policy's would (an untrained DT falls at once).

C MuJoCo episodes run ``--horizon`` steps; MJX, 10-40x slower here, ``--mjx-horizon`` (a rate, not a total).

``--dt-forward`` times the DT's forward pass alone on ``[episodes, K]`` contexts at the cpu and paper presets: the
full forward (every token, every layer) against the rollout policy's ``last_only`` forward (the last layer, the
final LayerNorm and the head for the last state token only), and checks they agree.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from minsubdt_jax.agents.base import PolicyInputs
from minsubdt_jax.agents.dt.agent import make_dt_agent
from minsubdt_jax.behavior.networks import policy_step
from minsubdt_jax.behavior.snapshots import load_policy
from minsubdt_jax.config import PRESETS
from minsubdt_jax.envs import env_spec, make_rollout, random_policy
from minsubdt_jax.envs.c_backend import default_threads
from minsubdt_jax.atomic import atomic_open


def make_policy(env: str, name: str, n: int):
    """``(policy, params, carry)`` for a row."""
    spec = env_spec(env)
    if name == "random":
        return random_policy, jnp.zeros(spec.act_dim), ()
    sac = load_policy(env, "expert")
    if name == "sac":
        return policy_step, sac, ()
    agent = make_dt_agent(PRESETS[name.split("-")[1]], spec.obs_dim, spec.act_dim, 1000)
    inputs = PolicyInputs(params=agent.init_params(jax.random.PRNGKey(0)), state_mean=jnp.zeros(spec.obs_dim),
                          state_std=jnp.ones(spec.obs_dim), target_return=jnp.float32(0.0),
                          rtg_scale=jnp.float32(1.0), subtract_rewards=jnp.float32(0.0))
    return _dt_on_sac(agent.policy), (inputs, sac), agent.initial_carry(n)


def _dt_on_sac(dt):
    def policy(params, carry, obs, prev_reward, t, rng):
        inputs, sac = params
        carry, a_dt = dt(inputs, carry, obs, prev_reward, t, rng)
        return carry, policy_step(sac, (), obs, prev_reward, t, rng)[1] + 1e-6 * a_dt

    return policy


def measure(env, backend, name, episodes, horizon):
    policy, params, carry = make_policy(env, name, episodes)
    run = make_rollout(env, policy, episodes, horizon, physics=backend)
    t0 = time.perf_counter()
    jax.block_until_ready(run(params, carry, jax.random.PRNGKey(1)))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    ro = jax.block_until_ready(run(params, carry, jax.random.PRNGKey(0)))
    s = time.perf_counter() - t0
    steps = int(np.asarray(ro.lengths).sum())
    return {"env": env, "physics": backend, "policy": name, "episodes": episodes, "horizon": horizon,
            "env_steps": steps, "seconds": s, "compile_s": max(first - s, 0.0), "env_steps_per_s": steps / s,
            "length_mean": steps / episodes}


def dt_forward(episodes: int, calls: int = 30) -> list[dict]:
    """Per-call time of the DT forward on ``episodes`` contexts of K = 20, full vs ``last_only``."""
    from minsubdt_jax.agents.dt.networks import DecisionTransformer

    rows = []
    for preset in ("cpu", "paper"):
        cfg = PRESETS[preset]
        model = DecisionTransformer(act_dim=6, embed_dim=cfg.embed_dim, n_layers=cfg.n_layers, n_heads=cfg.n_heads,
                                    dropout=cfg.dropout)
        B, K = episodes, cfg.context_len
        r = np.random.default_rng(0)
        x = (jnp.asarray(r.normal(size=(B, K, 17)), jnp.float32), jnp.asarray(r.uniform(-1, 1, (B, K, 6)), jnp.float32),
             jnp.asarray(r.normal(size=(B, K)), jnp.float32), jnp.tile(jnp.arange(K), (B, 1)), jnp.ones((B, K), bool))
        params = model.init(jax.random.PRNGKey(0), *x)
        full = jax.jit(lambda p, *a: model.apply(p, *a)[:, -1])
        last = jax.jit(lambda p, *a: model.apply(p, *a, last_only=True))
        out = {}
        for name, fn in (("full", full), ("last_only", last)):
            jax.block_until_ready(fn(params, *x))
            t0 = time.perf_counter()
            for _ in range(calls):
                jax.block_until_ready(fn(params, *x))
            out[name] = (time.perf_counter() - t0) / calls
        err = float(jnp.abs(full(params, *x) - last(params, *x)).max())
        rows.append({"preset": preset, "episodes": B, "full_ms": 1e3 * out["full"],
                     "last_only_ms": 1e3 * out["last_only"], "max_abs_diff": err})
        print(f"# DT forward, {preset} preset, {B} contexts: full {1e3 * out['full']:.2f} ms, last_only "
              f"{1e3 * out['last_only']:.2f} ms ({out['full'] / out['last_only']:.2f}x), max |diff| {err:.1e}",
              flush=True)
    return rows


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", nargs="+", default=["hopper", "walker", "halfcheetah"])
    p.add_argument("--backends", nargs="+", default=["mujoco", "mjx"], choices=["mujoco", "mjx"])
    p.add_argument("--policies", nargs="+", default=["random", "sac", "dt-cpu", "dt-paper"],
                   choices=["random", "sac", "dt-cpu", "dt-paper"])
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--horizon", type=int, default=1000)
    p.add_argument("--mjx-horizon", type=int, default=100)
    p.add_argument("--dt-forward", action="store_true", help="time only the DT forward, full vs last_only")
    p.add_argument("--json", default=None)
    a = p.parse_args()
    if a.dt_forward:
        rows = dt_forward(a.episodes)
        if a.json:
            with atomic_open(a.json) as fh:
                json.dump({"jax": jax.__version__, "rows": rows}, fh, indent=2)
        return
    dev = jax.devices()[0]
    print(f"# {a.episodes} episodes; C MuJoCo {default_threads()} threads, {a.horizon} steps; MJX {a.mjx_horizon} "
          f"steps; {dev.platform} {dev.device_kind}, {platform.processor() or platform.machine()}, "
          f"jax {jax.__version__}")
    print(f"{'env':>12} {'policy':>9} {'physics':>7} | {'env-steps':>9} {'seconds':>8} {'(compile)':>9} "
          f"{'mean len':>8} | {'env-steps/s':>11}")
    rows = []
    for env in a.envs:
        for name in a.policies:
            for backend in a.backends:
                r = measure(env_spec(env).name, backend, name, a.episodes,
                            a.horizon if backend == "mujoco" else a.mjx_horizon)
                rows.append(r)
                print(f"{r['env']:>12} {name:>9} {backend:>7} | {r['env_steps']:>9} {r['seconds']:>8.2f} "
                      f"{r['compile_s']:>9.1f} {r['length_mean']:>8.0f} | {r['env_steps_per_s']:>11.0f}", flush=True)
    for env in a.envs:
        for name in a.policies:
            got = {r["physics"]: r["env_steps_per_s"] for r in rows if r["env"] == env_spec(env).name
                   and r["policy"] == name}
            if len(got) == 2:
                print(f"# {env_spec(env).name} {name}: C MuJoCo / MJX = {got['mujoco'] / got['mjx']:.1f}x")
    if a.json:
        with atomic_open(a.json) as fh:
            json.dump({"device": f"{dev.platform} {dev.device_kind}", "jax": jax.__version__,
                       "threads": default_threads(), "rows": rows}, fh, indent=2)


if __name__ == "__main__":
    main()
