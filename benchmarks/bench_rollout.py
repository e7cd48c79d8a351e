"""Evaluation speed in MJX: a DT policy rolled out for 100 episodes x 1000 steps, batched vs one episode at a time
(C MuJoCo against MJX: ``bench_physics.py``).

    python benchmarks/bench_rollout.py                       # halfcheetah, cpu-preset DT, 100 x 1000
    python benchmarks/bench_rollout.py --env walker --sequential-episodes 100 --json out.json

Three ways to run the same policy (``minsubdt_jax.agents.dt.policy.dt_policy``, K = 20 context) on the same MJX env:

- ``batched``: all episodes in one jitted ``lax.while_loop`` over time, ``vmap`` over episodes (what
  ``minsubdt_jax.scoring.evaluate_policy`` does);
- ``sequential``: the official DT code's way: a Python loop over episodes and steps, one jitted policy call
  and one jitted ``env.step`` per step on a single environment;
- ``sequential-jit``: one episode at a time, but each episode is one jitted while-loop (batch 1), to separate
  the gain from batching from the gain from compiling the loop.

``--policy random`` runs uniform random actions instead of the DT: the physics alone, to show what bounds
the batched/sequential ratio. The DT has random weights (speed does not depend on them); halfcheetah never terminates, so every episode
runs the full horizon and env-steps are comparable across modes (on hopper and walker an untrained policy
falls early: steps are counted as actually simulated). The sequential modes time ``--sequential-episodes``
episodes and report env-steps/s; the time for all episodes is extrapolated from it and marked as such.
Compile time is reported apart.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from minsubdt_jax.config import PRESETS
from minsubdt_jax.envs import MjxEnv, env_spec, make_rollout, random_policy
from minsubdt_jax.agents.base import PolicyInputs
from minsubdt_jax.agents.dt.agent import make_dt_agent
from minsubdt_jax.atomic import atomic_open


def setup(env: str, preset: str, policy: str):
    """``(cfg, spec, policy_fn, params, carry(n))`` for the DT (random weights) or the uniform random policy."""
    cfg = PRESETS[preset]
    spec = env_spec(env)
    if policy == "random":
        return cfg, spec, random_policy, jnp.zeros(spec.act_dim), lambda n: ()
    agent = make_dt_agent(cfg, spec.obs_dim, spec.act_dim, 1000)
    params = PolicyInputs(params=agent.init_params(jax.random.PRNGKey(0)), state_mean=jnp.zeros(spec.obs_dim),
                          state_std=jnp.ones(spec.obs_dim), target_return=jnp.float32(0.0),
                          rtg_scale=jnp.float32(1.0), subtract_rewards=jnp.float32(0.0))
    return cfg, spec, agent.policy, params, agent.initial_carry


def batched(env, policy, params, carry, episodes, horizon, seed=0):
    """(seconds, env-steps, compile seconds): all episodes in one jitted call."""
    run = make_rollout(env, policy, episodes, horizon, physics="mjx")
    c = carry(episodes)
    t0 = time.perf_counter()
    jax.block_until_ready(run(params, c, jax.random.PRNGKey(seed + 1)))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    ro = jax.block_until_ready(run(params, c, jax.random.PRNGKey(seed)))
    s = time.perf_counter() - t0
    return s, int(np.asarray(ro.lengths).sum()), max(first - s, 0.0)


def sequential_jit(env, policy, params, carry, episodes, horizon, seed=0):
    """One episode at a time, each one jitted while-loop of batch 1."""
    run = make_rollout(env, policy, 1, horizon, physics="mjx")
    c = carry(1)
    t0 = time.perf_counter()
    jax.block_until_ready(run(params, c, jax.random.PRNGKey(10_000)))
    compile_s = time.perf_counter() - t0
    steps = 0
    t0 = time.perf_counter()
    for e in range(episodes):
        ro = jax.block_until_ready(run(params, c, jax.random.PRNGKey(seed + e)))
        steps += int(ro.lengths[0])
    s = time.perf_counter() - t0
    return s, steps, max(compile_s - s / episodes, 0.0)


def sequential_python(env, policy, params, carry, episodes, horizon, seed=0):
    """The official DT evaluation loop: Python over steps, one jitted policy call and env.step per step."""
    brax_env = MjxEnv(env)
    policy = jax.jit(policy)
    reset, step = jax.jit(brax_env.reset), jax.jit(brax_env.step)

    def episode(key):
        c = carry(1)
        state = reset(key)
        reward = jnp.zeros(1)
        for t in range(horizon):
            key, k = jax.random.split(key)
            c, action = policy(params, c, state.obs[None], reward, jnp.int32(t), k)
            state = step(state, jnp.clip(action[0], -1.0, 1.0))
            reward = state.reward[None]
            if float(state.done) > 0:  # one host sync per step, as a Python loop must do to stop
                return t + 1
        return horizon

    t0 = time.perf_counter()
    episode(jax.random.PRNGKey(10_000))  # compiles policy, reset and step
    first = time.perf_counter() - t0
    steps = 0
    t0 = time.perf_counter()
    for e in range(episodes):
        steps += episode(jax.random.PRNGKey(seed + e))
    s = time.perf_counter() - t0
    return s, steps, max(first - s / episodes, 0.0)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="halfcheetah")
    p.add_argument("--preset", default="cpu", choices=list(PRESETS))
    p.add_argument("--policy", default="dt", choices=["dt", "random"])
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--horizon", type=int, default=1000)
    p.add_argument("--sequential-episodes", type=int, default=3,
                   help="episodes timed in each sequential mode (the rate is extrapolated to --episodes)")
    p.add_argument("--modes", nargs="+", default=["batched", "sequential-jit", "sequential"],
                   choices=["batched", "sequential-jit", "sequential"])
    p.add_argument("--json", default=None)
    a = p.parse_args()
    if a.episodes < 1 or a.horizon < 1 or a.sequential_episodes < 1:
        p.error("--episodes, --horizon and --sequential-episodes must be >= 1")
    env = env_spec(a.env).name
    cfg, spec, policy, params, carry = setup(env, a.preset, a.policy)
    fns = {"batched": batched, "sequential-jit": sequential_jit, "sequential": sequential_python}
    dev = jax.devices()[0]
    who = (f"DT {a.preset} preset (K={cfg.context_len}, d={cfg.embed_dim}, {cfg.n_layers} layers)"
           if a.policy == "dt" else "uniform random actions (physics only)")
    print(f"# {env}, {who}, "
          f"{a.episodes} x {a.horizon} steps; {dev.platform} {dev.device_kind}, "
          f"{platform.processor() or platform.machine()}, jax {jax.__version__}")
    print(f"{'mode':>15} | {'episodes timed':>14} {'env-steps':>10} {'seconds':>9} {'(compile)':>9} | "
          f"{'env-steps/s':>11} {'s for all':>10} | {'batched / this':>14}")
    rows = []
    for mode in a.modes:
        n = a.episodes if mode == "batched" else min(a.sequential_episodes, a.episodes)
        s, steps, compile_s = fns[mode](env, policy, params, carry, n, a.horizon)
        rate = steps / s
        rows.append({"mode": mode, "episodes_timed": n, "env_steps": steps, "seconds": s, "compile_s": compile_s,
                     "env_steps_per_s": rate, "seconds_for_all_episodes": s * a.episodes / n,
                     "extrapolated": n != a.episodes})
    base = next((r["env_steps_per_s"] for r in rows if r["mode"] == "batched"), None)
    for r in rows:
        r["batched_over_this"] = base / r["env_steps_per_s"] if base else None
        mark = "*" if r["extrapolated"] else " "
        ratio = f"{r['batched_over_this']:>14.1f}" if base else f"{'-':>14}"
        print(f"{r['mode']:>15} | {r['episodes_timed']:>14} {r['env_steps']:>10} {r['seconds']:>9.2f} "
              f"{r['compile_s']:>9.1f} | {r['env_steps_per_s']:>11.0f} {r['seconds_for_all_episodes']:>9.1f}{mark} | "
              f"{ratio}", flush=True)
    if any(r["extrapolated"] for r in rows):
        print("# * extrapolated from the episodes timed")
    if a.json:
        with atomic_open(a.json) as fh:
            json.dump({"env": env, "policy": a.policy, "preset": a.preset, "episodes": a.episodes, "horizon": a.horizon,
                       "device": f"{dev.platform} {dev.device_kind}", "jax": jax.__version__, "rows": rows}, fh,
                      indent=2)


if __name__ == "__main__":
    main()
