"""The committed behaviour policies and normalisation references, and the command that exports them.

    python -m minsubdt_jax.behavior.policies --env hopper --run runs/behavior/hopper

Export reads a SAC run's ``snapshots.jsonl`` (see :mod:`minsubdt_jax.behavior.train`) and copies into
``behavior/snapshots/{env}/``:

* ``expert``: the snapshot with the best training-time evaluation;
* ``medium``: the earlier snapshot whose return, re-measured on ``--reference-episodes`` episodes, is
  0.35–0.6 of the expert's (the candidate nearest ``--medium-ratio`` first; D4RL v2's ratios were
  0.40 hopper, 0.58 walker, 0.45 halfcheetah);
* ``replay``: up to ``--replay`` snapshots evenly spaced up to and including medium (medium-replay's policies);

and writes ``manifest.json`` with the normalisation references measured here in brax dynamics (``--physics``: C
MuJoCo or MJX, ``auto`` by default): the uniform-random policy's and the expert's mean return over
``--reference-episodes`` stochastic 1000-step episodes.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys

import numpy as np

from ..caches import enable_compilation_cache
from ..envs import ENVS, PHYSICS, env_spec, resolve_physics
from ..rundir import exit_code
from .snapshots import POLICY_DIR, load_manifest, load_snapshot, measure_return
from .config import train_command
from ..atomic import atomic_open

MEDIUM_RANGE = (0.35, 0.6)


def export(env: str, run: str, medium_ratio: float = 0.45, replay: int = 8, reference_episodes: int = 100,
           verbose: bool = True, physics: str = "auto") -> dict:
    """Select expert / medium / replay snapshots of ``run``, measure references, write them under POLICY_DIR."""
    name = env_spec(env).name
    physics = resolve_physics(physics)
    with open(os.path.join(run, "snapshots.jsonl")) as f:
        snaps = [json.loads(ln) for ln in f if ln.strip()]
    if not snaps:
        raise ValueError(f"{run}: no snapshots yet")
    load = lambda s: load_snapshot(os.path.join(run, "snapshots", s["snapshot"]))[0]  # noqa: E731
    say = print if verbose else (lambda *a, **k: None)

    expert = max(snaps, key=lambda s: s["return_mean"])
    ref_expert = measure_return(name, load(expert), reference_episodes, seed=1, physics=physics)
    ref_random = measure_return(name, None, reference_episodes, seed=2, physics=physics)
    say(f"expert step {expert['step']}: {ref_expert['return_mean']:.1f} ± {ref_expert['return_std']:.1f}; "
        f"random {ref_random['return_mean']:.1f}")
    lo, hi = ref_random["return_mean"], ref_expert["return_mean"]
    ratio = lambda r: (r - lo) / (hi - lo)  # noqa: E731
    candidates = sorted((s for s in snaps if s["step"] < expert["step"]
                         and MEDIUM_RANGE[0] <= ratio(s["return_mean"]) <= MEDIUM_RANGE[1]),
                        key=lambda s: abs(ratio(s["return_mean"]) - medium_ratio))
    medium = None
    for s in candidates:
        m = measure_return(name, load(s), reference_episodes, seed=3, physics=physics)
        say(f"medium candidate step {s['step']}: {m['return_mean']:.1f} (ratio {ratio(m['return_mean']):.2f})")
        if MEDIUM_RANGE[0] <= ratio(m["return_mean"]) <= MEDIUM_RANGE[1]:
            medium = {**s, "measured": m, "ratio": ratio(m["return_mean"])}
            break
    if medium is None:
        raise ValueError(f"{run}: no snapshot before the expert has a return within {MEDIUM_RANGE} of the expert's")
    early = [s for s in snaps if s["step"] <= medium["step"]]
    picks = sorted({int(round(i)) for i in np.linspace(0, len(early) - 1, min(replay, len(early)))})
    replay_snaps = [early[i] for i in picks]

    out = os.path.join(POLICY_DIR, name)
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    for s in {s["snapshot"]: s for s in [expert, medium, *replay_snaps]}.values():
        shutil.copy(os.path.join(run, "snapshots", s["snapshot"]), out)
    with open(os.path.join(run, "config.json")) as f:
        run_cfg = json.load(f)
    with open(os.path.join(run, "metrics.jsonl")) as f:
        last = [json.loads(ln) for ln in f if ln.strip()][-1]
    keep = ("step", "snapshot", "return_mean", "return_std", "episodes", "wall_seconds")
    manifest = {
        "env": name,
        "references": {"random": ref_random, "expert": ref_expert, "physics": physics, "dynamics": "brax"},
        "expert": {k: expert[k] for k in keep},
        "medium": {**{k: medium[k] for k in keep}, "measured": medium["measured"], "ratio": medium["ratio"]},
        "replay": [{k: s[k] for k in keep} for s in replay_snaps],
        "training": {"config": run_cfg, "env_steps": last["step"], "wall_seconds": last["wall_seconds"],
                     "curve": [{k: s[k] for k in ("step", "wall_seconds", "return_mean")} for s in snaps]},
        # --steps: where the run's snapshots end (a run may be stopped early, or resumed further)
        "commands": [train_command({**run_cfg, "steps": snaps[-1]["step"], "out": None}),
                     f"python -m minsubdt_jax.behavior.policies --env {name} --run {run} --medium-ratio "
                     f"{medium_ratio} --replay {replay} --reference-episodes {reference_episodes} --physics {physics}"],
    }
    with atomic_open(os.path.join(out, "manifest.json")) as f:
        json.dump(manifest, f, indent=1)
    load_manifest.cache_clear()
    say(f"medium step {medium['step']} (ratio {medium['ratio']:.2f}); replay steps "
        f"{[s['step'] for s in replay_snaps]} -> {out}")
    return manifest


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m minsubdt_jax.behavior.policies", description=__doc__.split("\n")[0])
    p.add_argument("--env", required=True, choices=tuple(ENVS))
    p.add_argument("--run", required=True, help="a behavior.train run directory")
    p.add_argument("--medium-ratio", type=float, default=0.45)
    p.add_argument("--replay", type=int, default=8)
    p.add_argument("--reference-episodes", type=int, default=100)
    p.add_argument("--physics", choices=PHYSICS, default="auto",
                   help="who steps the reference episodes: C MuJoCo (mujoco), MJX, or auto (C MuJoCo on a CPU)")
    a = p.parse_args(argv)
    enable_compilation_cache()
    return exit_code(lambda: export(a.env, a.run, a.medium_ratio, a.replay, a.reference_episodes, physics=a.physics))


if __name__ == "__main__":
    sys.exit(main())
