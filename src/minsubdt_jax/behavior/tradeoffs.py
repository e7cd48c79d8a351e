"""Behaviour policies at several trade-offs between speed and energy (issue 74): the sources of the multi-preference
datasets ``mo-expert`` and ``mo-amateur``, as PGMORL's Pareto-archive policies are D4MORL's (PEDA, Zhu et al. 2023).

Each is a SAC policy (:mod:`minsubdt_jax.behavior.train`) trained on ``r = v_x - lambda * |a|^2`` (plus the healthy
reward of hopper and walker): ``--energy-weight lambda``, MO-Gymnasium's two objectives ``[v_x, -|a|^2]``
scalarised with the weights ``(1, lambda)``, so its preference is ``omega = (1, lambda) / (1 + lambda)``. A grid of
lambda (:data:`ENERGY_WEIGHTS`) rather than one preference-conditioned SAC (CAPQL): each point is the trainer this
library already tests, one resumable lane unit, and a failed point is retrained alone.

    python -m minsubdt_jax.behavior.train --env halfcheetah --energy-weight 0.5 --steps 200000 --out R/0.5
    python -m minsubdt_jax.behavior.tradeoffs --env halfcheetah --runs R/0.1 R/0.5 ...   # export the family

Export copies each run's snapshot with the best training objective into ``behavior/snapshots/{env}/tradeoffs/`` and
writes its ``manifest.json``: per policy its lambda, preference and its objectives measured on ``--episodes``
stochastic episodes (:func:`objectives`: the episode sums of ``v_x`` and of ``|a|^2``). Those points are the
behaviour front; their cost-metric front is scored where the cost metrics live (``experiments/``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys

import jax
import numpy as np

from ..atomic import atomic_open
from ..envs import ENVS, PHYSICS, env_spec, resolve_physics
from ..rundir import exit_code
from .snapshots import POLICY_DIR, load_snapshot, make_policy_rollout

# the lane's grid of lambda per env (experiments/queue.sh behavior): from the env's own control cost, where speed
# rules, to weights where standing still pays (hopper and walker keep their healthy reward there)
ENERGY_WEIGHTS = {"halfcheetah": (0.1, 0.3, 0.6, 1.2, 2.5), "hopper": (0.001, 0.1, 0.3, 0.6, 1.2),
                  "walker": (0.001, 0.1, 0.3, 0.6, 1.2)}


def objectives(env: str, rollout) -> tuple[np.ndarray, np.ndarray]:
    """``(speed [n], energy [n])``: each episode's sum over its steps of the forward velocity ``v_x`` (read from the
    observation, as the ``x_velocity`` cost metric is) and of ``|a|^2`` (MO-Gymnasium's objectives ``v_x`` and
    ``-|a|^2``, the healthy bonus left out). Padding past an episode's end is zero in a ``Rollout``."""
    obs, act = np.asarray(rollout.observations), np.asarray(rollout.actions)
    return obs[..., env_spec(env).x_velocity_index].sum(1), np.square(act).sum((1, 2))


def preference(energy_weight: float) -> list[float]:
    """The preference ``omega = (speed, energy)`` of a policy trained with ``energy_weight`` (they sum to 1)."""
    return [1.0 / (1.0 + energy_weight), energy_weight / (1.0 + energy_weight)]


def family_dir(env: str) -> str:
    return os.path.join(POLICY_DIR, env_spec(env).name, "tradeoffs")


def load_manifest(env: str) -> dict:
    """The committed trade-off family of ``env``; one clear error where it has none."""
    path = os.path.join(family_dir(env), "manifest.json")
    if not os.path.exists(path):
        raise ValueError(f"no trade-off behaviour policies for {env!r} in {family_dir(env)}: train them with "
                         f"`bash experiments/queue.sh behavior` (experiments/tradeoff_policies.py)")
    with open(path) as f:
        return json.load(f)


def load_policies(env: str) -> list[tuple]:
    """``[(actor_params, record)]`` of the family, lowest energy weight first."""
    return [(load_snapshot(os.path.join(family_dir(env), p["snapshot"]))[0], p) for p in load_manifest(env)["policies"]]


def measure(env: str, actor_params, episodes: int, seed: int = 0, physics: str = "auto") -> dict:
    """Return, objectives (their means and standard deviations over episodes) and mean length of the stochastic
    actor over ``episodes`` 1000-step episodes."""
    run, params = make_policy_rollout(env, actor_params, episodes, 1000, physics)
    ro = jax.device_get(run(params, (), jax.random.PRNGKey(seed)))
    speed, energy = objectives(env, ro)
    ret = np.asarray(ro.rewards).sum(1)
    return {"episodes": episodes, "return_mean": float(ret.mean()), "speed_mean": float(speed.mean()),
            "speed_std": float(speed.std()), "energy_mean": float(energy.mean()), "energy_std": float(energy.std()),
            "length_mean": float(np.mean(ro.lengths))}


def export(env: str, runs: list[str], episodes: int = 100, physics: str = "auto", verbose: bool = True) -> dict:
    """Each run's snapshot with the best training objective (``objective_mean`` of its evaluations), measured on
    ``episodes`` episodes, into :func:`family_dir`, beside the family's policies of other energy weights already
    there (a family grows run by run); the manifest, lowest energy weight first."""
    physics, say = resolve_physics(physics), (print if verbose else (lambda *a, **k: None))
    policies = []
    for run in runs:
        with open(os.path.join(run, "config.json")) as f:
            cfg = json.load(f)
        if cfg.get("env") != env_spec(env).name or cfg.get("energy_weight") is None:
            raise ValueError(f"{run}: not a {env} trade-off run (its config has env {cfg.get('env')!r}, "
                             f"energy_weight {cfg.get('energy_weight')!r})")
        with open(os.path.join(run, "snapshots.jsonl")) as f:
            snaps = [json.loads(ln) for ln in f if ln.strip()]
        if not snaps:
            raise ValueError(f"{run}: no snapshots yet")
        best = max(snaps, key=lambda s: s["objective_mean"])
        lam = float(cfg["energy_weight"])
        m = measure(env, load_snapshot(os.path.join(run, "snapshots", best["snapshot"]))[0], episodes, physics=physics)
        policies.append({"energy_weight": lam, "preference": preference(lam), "snapshot": f"lambda{lam:g}.npz",
                         "step": best["step"], "objective_mean": best["objective_mean"], "measured": m,
                         "run": run, "source": best["snapshot"], "train_steps": cfg["steps"]})
        say(f"lambda {lam:g}: step {best['step']}, speed {m['speed_mean']:.0f}, energy {m['energy_mean']:.0f}, "
            f"return {m['return_mean']:.0f}, length {m['length_mean']:.0f}")
    if len({p["energy_weight"] for p in policies}) != len(policies):
        raise ValueError("two runs have the same --energy-weight")
    out, new = family_dir(env), {p["energy_weight"] for p in policies}
    kept = [p for p in load_manifest(env)["policies"] if p["energy_weight"] not in new] if os.path.exists(
        os.path.join(out, "manifest.json")) else []
    os.makedirs(out, exist_ok=True)
    for p in policies:
        shutil.copy(os.path.join(p["run"], "snapshots", p["source"]), os.path.join(out, p["snapshot"]))
    policies = sorted(kept + policies, key=lambda p: p["energy_weight"])
    manifest = {"env": env_spec(env).name, "physics": physics, "dynamics": "brax", "policies": policies,
                "objectives": "episode sums of v_x (speed) and |a|^2 (energy), stochastic actor, 1000-step episodes"}
    with atomic_open(os.path.join(out, "manifest.json")) as f:
        json.dump(manifest, f, indent=1)
    return manifest


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m minsubdt_jax.behavior.tradeoffs", description=__doc__.split("\n")[0])
    p.add_argument("--env", required=True, choices=tuple(ENVS))
    p.add_argument("--runs", required=True, nargs="+", help="behavior.train run directories with --energy-weight")
    p.add_argument("--episodes", type=int, default=100, help="episodes each policy is measured on")
    p.add_argument("--physics", choices=PHYSICS, default="auto")
    a = p.parse_args(argv)
    return exit_code(lambda: export(a.env, a.runs, a.episodes, a.physics))


if __name__ == "__main__":
    sys.exit(main())
