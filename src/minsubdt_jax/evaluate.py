"""A trained run's policy at a target of one's choosing, without retraining (issue 55).

    python -m minsubdt_jax.evaluate RUN_DIR --target x_velocity=0,energy@lived=0.5 --episodes 100
    python -m minsubdt_jax.evaluate RUN_DIR --target 0.5          # a method with one return token: one number

A vector method (``minsubdt-vec``, ``dt-vec``: :mod:`minsubdt_jax.methods`) takes a target per cost metric, each
in ``[0, bound]``: for ``minsubdt-vec`` eq. 2's per-metric term (0: beat every demo in that metric; ``beta``: the
metric does not matter), for ``dt-vec`` the metric's cost itself (0 the best, 1 the worst). A metric left out keeps
the method's default (0, or the demos' best cost). A method with one return token takes one number, its return token
(as ``--target-return``). Every model of the run (``--method``: one of its methods) is rolled out in one batched
program, and the results are written beside the run, ``RUN_DIR/evaluations/<method>/<target>.json``.

In a gymnasium loop (:mod:`minsubdt_jax.envs.gym_env`), :func:`load_policy` keeps its own context::

    policy = load_policy("runs/walker", target={"x_velocity": 0.0, "energy@lived": 0.5})
    obs, _ = env.reset(seed=0); policy.reset(); reward = 0.0
    while True:
        obs, reward, term, trunc, _ = env.step(policy(obs, reward))
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

from .agents import batch_size_of
from .agents.base import PolicyInputs, eval_params, init_seed_states, optimizer_for
from .config import Config, validate
from .costs import cost_metrics
from .envs import resolve_physics
from .scoring import across_seeds
from .flags import load_fields
from .methods import get_method
from .parallel import available_bytes, make_mesh
from .pipeline import load
from .program import evaluate_models, program_models
from .rundir import (COST_METRICS_FILE, DATASET_FILE, check_same_data, check_same_metrics, exit_code, json_text,
                     write_atomic)
from .runsetup import prepare_each, program_agent, restore_latest
from .targets import parse_preference, target_token


@dataclasses.dataclass(frozen=True)
class LoadedRun:
    """A run directory read back: its config, agent, models (:class:`~minsubdt_jax.program.Model`), their evaluated parameters
    ``[M, ...]`` (the moving average where one was kept) at checkpoint ``step``, and their prepared data."""

    cfg: Config
    agent: object
    models: list
    params: object
    per_model: list
    dynamics: str
    step: int


def load_run(run_dir: str, metrics=None) -> LoadedRun:
    """Read ``run_dir`` (``config.json``, ``dataset.json``, the last checkpoint) and rebuild what evaluating its
    models needs. ``metrics``: the cost metrics, for a run trained on metrics of one's own. Raises ValueError on a
    folder that is not a finished or checkpointed run, or whose dataset has changed since."""
    paths = {n: os.path.join(run_dir, n) for n in ("config.json", DATASET_FILE, COST_METRICS_FILE, "checkpoints")}
    missing = [n for n, p in paths.items() if not os.path.exists(p)]
    if missing:
        raise ValueError(f"{run_dir}: not a run directory with a checkpoint (no {', '.join(missing)})")
    cfg = validate(dataclasses.replace(Config(), **load_fields(paths["config.json"], Config, "config.json")))
    if len(cfg.datasets) > 1:
        raise ValueError(f"{run_dir}: trained on several datasets ({cfg.dataset}); evaluate a one-dataset run")
    with open(paths[DATASET_FILE]) as f:
        recorded = json.load(f)
    chosen = cost_metrics(cfg.env, cfg.costs if metrics is None else metrics)
    check_same_metrics(run_dir, [m.record() for m in chosen], True, what=run_dir)  # as a resume checks them
    source = load(cfg, verbose=False, physics=recorded.get("recorded_physics"))
    check_same_data(run_dir, source.sha256, True, what=run_dir)
    methods = [get_method(m) for m in cfg.methods]
    models = program_models(methods, list(range(cfg.seed, cfg.seed + cfg.seeds)), cfg.datasets)
    _, per_model = prepare_each(cfg, models, [source], recorded["dynamics"], metrics, verbose=False)
    agent = program_agent(cfg, methods, [source], len(chosen))
    template = init_seed_states(agent, optimizer_for(agent, cfg), [mo.seed for mo in models], ema=cfg.ema_decay > 0)
    state, mngr = restore_latest(run_dir, template)  # training's own restore
    if mngr.latest_step() is None:
        raise ValueError(f"{run_dir}: no checkpoint has been written yet")
    return LoadedRun(cfg, agent, models, eval_params(state), per_model, recorded["dynamics"], int(mngr.latest_step()))


def _select(run: LoadedRun, method: str | None, seed: int | None = None) -> list[int]:
    names = [mo.method.name for mo in run.models]
    if method is None and len(set(names)) > 1:
        raise ValueError(f"the run trained {sorted(set(names))}: choose one with --method")
    idx = [i for i, mo in enumerate(run.models) if (method is None or mo.method.name == method)
           and (seed is None or mo.seed == seed)]
    if not idx:
        raise ValueError(f"the run has no model of method {method!r} and seed {seed!r}; it has "
                         f"{[(mo.method.name, mo.seed) for mo in run.models]}")
    return idx


def evaluate_run(run_dir: str, target=None, episodes: int = 100, method: str | None = None, metrics=None,
                 write: bool = True, run: LoadedRun | None = None, preference=None) -> dict:
    """Roll out every seed of ``method`` (the run's one, by default) in ``run_dir`` conditioned on ``target``
    (:func:`~minsubdt_jax.targets.parse_target`), or on a ``preference`` over the cost metrics mapped onto the data's
    front (:func:`~minsubdt_jax.targets.preference_target`), else the run's own target, that of its final
    evaluation, for ``episodes`` episodes each; the result (per seed and across seeds, as ``results.json``'s) is
    written to ``RUN_DIR/evaluations/<method>/<target>.json`` (``pref-<preference>.json``) and returned."""
    run = run or load_run(run_dir, metrics)
    idx = _select(run, method)
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {episodes}")
    check_rollout_memory(run.per_model[idx[0]], len(idx), episodes, run.cfg.episode_length)
    m = run.models[idx[0]].method
    token, omega = target_token(m, run.per_model[idx[0]], run.cfg.beta, target, preference)
    per_model = [dataclasses.replace(run.per_model[i], target_return=token, preference=omega) for i in idx]
    mesh = make_mesh(run.cfg.devices, batch_size_of(m.agent, run.cfg))
    params = jax.tree.map(lambda x: x[np.asarray(idx)], run.params)
    per = evaluate_models(run.cfg, run.agent, params, [run.models[i] for i in idx], per_model, mesh, episodes,
                          physics=resolve_physics(run.cfg.physics, mesh), dynamics=run.dynamics)
    names = [x.name for x in per_model[0].metrics]
    asked = ({n: 0.0 - float(v) for n, v in zip(names, np.atleast_1d(token))} if m.vector else float(token))
    out = {"run": run_dir, "method": m.name, "checkpoint_step": run.step, "target": asked, "episodes": episodes,
           "eval": per[0] if len(per) == 1 else across_seeds(per), "eval_per_model": per}
    if preference is not None:
        out["preference"] = dict(zip(names, parse_preference(preference, names).tolist()))
    if write:
        shown = out.get("preference") or (asked if m.vector else None)  # a preference names its file (bc-p too)
        label = ",".join(f"{n}={v:g}" for n, v in shown.items()) if shown else f"{asked:g}"
        label = ("pref-" if preference is not None else "") + label
        os.makedirs(os.path.join(run_dir, "evaluations", m.name), exist_ok=True)
        write_atomic(os.path.join(run_dir, "evaluations", m.name, label + ".json"), json_text(out, indent=2))
    return out


def check_rollout_memory(prep, n_models: int, episodes: int, horizon: int) -> None:
    """An episode count whose rollouts cannot fit in memory is one error before anything runs (it was an
    out-of-memory kill): the episodes' observations, actions and rewards, ``[models, episodes, horizon, ...]``
    float32, are kept for scoring."""
    need = 4 * n_models * episodes * horizon * (prep.state_mean.shape[-1] + prep.source.data.actions.shape[-1] + 4)
    have = available_bytes()
    if have is not None and need > have:
        raise ValueError(f"--episodes {episodes}: {n_models} model(s) x {episodes} episodes of {horizon} steps need "
                         f"~{need / 2 ** 30:,.1f} GiB, more than the {have / 2 ** 30:.1f} GiB available")


class Policy:
    """One model of a run as a policy for a gymnasium loop: ``policy(obs, reward) -> action`` (``reward``: the last
    step's, which a DT on true returns subtracts from its return-to-go), its context kept between calls;
    ``reset()`` before each episode."""

    def __init__(self, run: LoadedRun, i: int, token, preference=None):
        p = run.per_model[i]
        self.agent, self.target, self.preference = run.agent, token, preference
        self.inputs = PolicyInputs(params=jax.tree.map(lambda x: x[i], run.params), state_mean=jnp.asarray(p.state_mean),
                                   state_std=jnp.asarray(p.state_std), target_return=jnp.asarray(token, jnp.float32),
                                   rtg_scale=jnp.float32(p.rtg_scale),
                                   subtract_rewards=jnp.float32(run.models[i].method.subtract_rewards),
                                   preference=None if preference is None else jnp.asarray(preference, jnp.float32))
        self._act = jax.jit(run.agent.policy)
        self.reset()

    def reset(self) -> None:
        self.carry, self.t, self.key = self.agent.initial_carry(1), 0, jax.random.PRNGKey(0)

    def __call__(self, obs, reward: float = 0.0) -> np.ndarray:
        """The action ``[act]`` for ``obs [obs_dim]`` after ``reward``; ValueError on any other shape or a value
        that is not finite (the model would answer NaN)."""
        want = (self.inputs.state_mean.shape[-1] - (0 if self.preference is None else len(self.preference)),)
        obs = np.asarray(obs, np.float32)
        if obs.shape != want:
            raise ValueError(f"the policy takes an observation of shape {want}, got {obs.shape}")
        if not np.isfinite(obs).all():
            raise ValueError(f"the observation is not finite: {obs}")
        if not np.isfinite(np.float32(reward)):
            raise ValueError(f"the reward is not finite: {reward}")
        self.key, k = jax.random.split(self.key)
        obs = jnp.asarray(obs)[None]
        self.carry, action = self._act(self.inputs, self.carry, obs, jnp.float32(reward)[None], jnp.int32(self.t), k)
        self.t += 1
        return np.asarray(action[0])


def load_policy(run_dir: str, target=None, method: str | None = None, seed: int | None = None,
                metrics=None, preference=None) -> Policy:
    """The policy of the run's model of ``method`` and ``seed`` (the run's first seed by default) conditioned on
    ``target`` (:func:`~minsubdt_jax.targets.parse_target`) or ``preference`` (weights over the cost metrics:
    :func:`~minsubdt_jax.targets.preference_target`); neither: the method's default."""
    run = load_run(run_dir, metrics)
    i = _select(run, method, seed)[0]
    return Policy(run, i, *target_token(run.models[i].method, run.per_model[i], run.cfg.beta, target, preference, ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m minsubdt_jax.evaluate", description="Roll out a trained run's "
                                 "models at a target of one's choosing and write the results beside the run.")
    ap.add_argument("run_dir", help="a run directory (python -m minsubdt_jax.train ... --out RUN_DIR)")
    ap.add_argument("--target", help="name=value per cost metric (comma-separated) for minsubdt-vec and dt-vec; one "
                    "number for a method with one return token (default: the run's own target)")
    ap.add_argument("--preference", help="weights over the cost metrics (name=w,... or w1,w2 in the run's metric "
                    "order) for minsubdt-vec and dt-vec: the target is the return token of the data's episode that "
                    "serves them best (minsubdt_jax.targets)")
    ap.add_argument("--episodes", type=int, default=100, help="episodes per seed (100)")
    ap.add_argument("--method", help="the method to evaluate, for a run that trained several")
    a = ap.parse_args(argv)

    def run():
        out = evaluate_run(a.run_dir, a.target, a.episodes, a.method, preference=a.preference)
        e = out["eval"]
        at = (",".join(f"{k}={v:g}" for k, v in out["target"].items()) if isinstance(out["target"], dict)
              else f"{out['target']:g}")
        print(f"{out['method']} at {at}: normalised {e['normalized_score_mean']:.1f}, costs "
              + ", ".join(f"{k} {v:.3f}" for k, v in e["costs_mean"].items()) + f" ({len(out['eval_per_model'])} "
              f"seed(s) x {a.episodes} episodes); wrote {a.run_dir}/evaluations/{out['method']}/")
    return exit_code(run)


if __name__ == "__main__":
    sys.exit(main())
