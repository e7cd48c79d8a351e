"""Scoring of any policy: batched rollouts (MJX or C MuJoCo) and their scores (a trained run re-scored from its
directory is :mod:`minsubdt_jax.evaluate`).


* :func:`rollout_seeds` rolls out S models of one policy (any agent's, :mod:`minsubdt_jax.agents`) in one program
  (``vmap`` over the seed axis of the policy inputs; in MJX the episodes split over a device mesh);
* :func:`score_episodes` scores recorded episodes, whoever acted: return, normalised score, engineered cost
  features, and, given the demos, min-subdominance against them (eq. 2) and the better-than-demonstrated test.
  Dataset recording summarises its episodes with it too (:mod:`minsubdt_jax.data.named`);
* :func:`evaluate_policy` is the two together; :func:`across_seeds` summarises several seeds.

The physics (``mjx``, ``mujoco``, ``auto``) and the env rules (``dynamics``: ``brax`` or ``d4rl``) are
:mod:`minsubdt_jax.envs`'; scores are normalised with the references of the dynamics
(:mod:`minsubdt_jax.references`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .costs import CostMetric, cost_metrics, trajectory_costs
from .envs import make_seed_rollout
from .parallel import gather
from .references import references_for
from .subdominance import min_subdominance


@dataclass
class EvalResult:
    """Per-episode results (numpy): returns ``[n]``, lengths ``[n]``, normalized ``[n]``, costs ``[n, K]``
    (engineered cost features); with demos: min_subdominance ``[n]`` against the demos' engineered features and
    beats_mean_demo ``[n]`` (dominates the demos' mean: no engineered feature above it, one below); for learned costs,
    learned_min_subdominance ``[n]`` against the demos' learned features."""

    returns: np.ndarray
    lengths: np.ndarray
    normalized: np.ndarray
    costs: np.ndarray
    cost_names: tuple[str, ...]
    min_subdominance: np.ndarray | None = None
    beats_mean_demo: np.ndarray | None = None
    learned_min_subdominance: np.ndarray | None = None

    def summary(self) -> dict:
        """The JSON summary written to ``results.json`` (means, stds, and the per-episode returns and costs)."""
        out = {
            "episodes": int(len(self.returns)),
            "return_mean": float(self.returns.mean()), "return_std": float(self.returns.std()),
            "normalized_score_mean": float(self.normalized.mean()),
            "normalized_score_std": float(self.normalized.std()),
            "length_mean": float(self.lengths.mean()),
            "costs_mean": {n: float(v) for n, v in zip(self.cost_names, self.costs.mean(0))},
        }
        if self.min_subdominance is not None:
            out["min_subdominance_mean"] = float(self.min_subdominance.mean())
            out["min_subdominance_std"] = float(self.min_subdominance.std())
            out["better_than_mean_demo_share"] = float(self.beats_mean_demo.mean())
        if self.learned_min_subdominance is not None:
            out["learned_min_subdominance_mean"] = float(self.learned_min_subdominance.mean())
            out["learned_min_subdominance_std"] = float(self.learned_min_subdominance.std())
        return {**out, "returns": self.returns.tolist(), "costs": self.costs.tolist()}


@dataclass(frozen=True)
class Scoring:
    """How episodes are scored (:func:`score_episodes`).

    With ``demo_costs [M, K]`` (the dataset's engineered features) each episode's min-subdominance (eq. 2, margin
    ``beta``, cap ``alpha_max``) against them is computed, and whether it beats their mean on every feature.
    With ``learned`` (a :class:`~minsubdt_jax.learned_costs.LearnedCosts`) and ``demo_features [M, K']``, the
    min-subdominance on the learned features too (for :func:`evaluate_policy`, lists of S: one per seed).
    Normalised with ``references`` (:class:`~minsubdt_jax.references.References`: a dataset's own), else those of
    ``dynamics`` (the env rules the episodes ran in). The cost features are ``metrics``' (default: the env's,
    :func:`~minsubdt_jax.costs.cost_metrics`); ``extra_metrics`` (``--eval-costs``) add columns that are reported
    only: min-subdominance and beating the mean demo use ``metrics``' columns, which come first."""

    demo_costs: Any = None
    beta: float = 1.0
    alpha_max: float | None = None
    learned: Any = None
    demo_features: Any = None
    metrics: tuple[CostMetric, ...] | None = None
    extra_metrics: tuple[CostMetric, ...] = ()
    dynamics: str = "brax"
    references: Any = None

    def of_seed(self, i: int) -> "Scoring":
        """The scoring of seed ``i`` where the learned costs are per seed."""
        if self.learned is None:
            return self
        return dataclasses.replace(self, learned=self.learned[i], demo_features=self.demo_features[i])


def score_episodes(env: str, observations, lengths, rewards, *, terminated, horizon: int, actions=None,
                   scoring: Scoring = Scoring()) -> EvalResult:
    """Score episodes ``observations [n, T, obs]``, ``lengths [n]``, ``rewards [n, T]`` (padding ignored),
    ``terminated [n]`` (ended by a fall, else by the horizon: costs treat the two apart, :mod:`minsubdt_jax.costs`),
    as ``scoring`` says (:class:`Scoring`); the cost features are read from the observations and
    ``actions [n, T, act]``."""
    sc = scoring
    lengths = np.asarray(lengths)
    valid = np.arange(np.shape(rewards)[1])[None, :] < lengths[:, None]
    returns = np.where(valid, np.asarray(rewards), 0.0).sum(1)
    metrics = cost_metrics(env) if sc.metrics is None else tuple(sc.metrics)
    k = len(metrics)
    extra = tuple(m for m in sc.extra_metrics if m.name not in {n.name for n in metrics})
    costs = np.asarray(trajectory_costs(metrics + extra, observations, lengths, horizon, terminated=terminated,
                                        actions=actions))
    refs = sc.references or references_for(env, sc.dynamics)
    ev = EvalResult(returns=returns, lengths=lengths, normalized=refs.normalize(returns), costs=costs,
                    cost_names=tuple(m.name for m in metrics + extra))
    if sc.demo_costs is not None:
        demo_costs, own = np.asarray(sc.demo_costs), costs[:, :k]
        ev.min_subdominance = np.asarray(min_subdominance(own, demo_costs, sc.beta, alpha_max=sc.alpha_max).value)
        mean = demo_costs.mean(0)  # dominates the mean demo: no worse on any feature, better on one
        ev.beats_mean_demo = np.all(own <= mean, axis=1) & np.any(own < mean, axis=1)
    if sc.learned is not None:
        feats = sc.learned.features(observations, lengths, terminated)
        ev.learned_min_subdominance = np.asarray(
            min_subdominance(feats, np.asarray(sc.demo_features), sc.beta, alpha_max=sc.alpha_max).value)
    return ev


def rollout_seeds(env: str, policy, inputs, carry, *, num_episodes: int, horizon: int, seeds, mesh=None,
                  physics: str = "auto", dynamics: str = "brax", threads: int = 0):
    """Roll out S models of ``policy``: ``inputs`` (its traced inputs) has a leading seed axis ``[S, ...]``, ``carry``
    is the policy's initial carry for ``n_run`` episodes, ``seeds [S]`` seed each model's episodes.

    With a ``mesh`` each seed's episodes are split over its devices, in every process of a multi-process job; the
    number rolled out, ``n_run``, is ``num_episodes`` rounded up to a multiple of the mesh size (see
    :func:`episodes_to_run`), and the caller scores the first ``num_episodes``, so the result does not depend on
    the device count. ``physics``, ``dynamics``, ``threads``: see :func:`minsubdt_jax.envs.make_rollout`.
    Returns the gathered :class:`~minsubdt_jax.envs.Rollout` ``[S, n_run, ...]``."""
    n_run = episodes_to_run(num_episodes, mesh)
    run = make_seed_rollout(env, policy, n_run, horizon, mesh, physics=physics, dynamics=dynamics, threads=threads)
    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    return gather(run(inputs, carry, keys))


def episodes_to_run(num_episodes: int, mesh=None) -> int:
    size = 1 if mesh is None else mesh.size
    return -(-num_episodes // size) * size


def evaluate_policy(env: str, agent, inputs, *, num_episodes: int, horizon: int, seeds, scoring: Scoring,
                    mesh=None, physics: str = "auto", threads: int = 0) -> list[EvalResult]:
    """Roll out ``agent``'s policy for S models (``inputs [S, ...]``, :class:`~minsubdt_jax.agents.base.PolicyInputs`)
    and score each seed's first ``num_episodes`` episodes against the demos (:func:`score_episodes`, ``scoring``:
    its learned costs, when given, one per seed). The episodes run in ``physics`` under ``scoring.dynamics``."""
    carry = agent.initial_carry(episodes_to_run(num_episodes, mesh))
    ro = rollout_seeds(env, agent.policy, inputs, carry, num_episodes=num_episodes, horizon=horizon, seeds=seeds,
                       mesh=mesh, physics=physics, dynamics=scoring.dynamics, threads=threads)
    return [score_episodes(env, ro.observations[i, :num_episodes], ro.lengths[i, :num_episodes],
                           ro.rewards[i, :num_episodes], terminated=ro.terminated[i, :num_episodes],
                           horizon=horizon, actions=ro.actions[i, :num_episodes], scoring=scoring.of_seed(i))
            for i in range(len(seeds))]


def across_seeds(evals: list[dict]) -> dict:
    """The seed-level summary of a multi-seed run: mean ± std over seeds (n = S) of each seed's mean, and every
    seed's episodes pooled for ``returns`` and ``costs``."""
    out = {"seeds": [e["seed"] for e in evals], "episodes": sum(e["episodes"] for e in evals)}
    for base in ("return", "normalized_score", "min_subdominance", "learned_min_subdominance"):
        if base + "_mean" in evals[0]:
            v = np.array([e[base + "_mean"] for e in evals])
            out.update({base + "_mean": float(v.mean()), base + "_std": float(v.std()), base + "_per_seed": v.tolist()})
    for key in ("length_mean", "better_than_mean_demo_share"):
        out[key] = float(np.mean([e[key] for e in evals]))
    out["costs_mean"] = {k: float(np.mean([e["costs_mean"][k] for e in evals])) for k in evals[0]["costs_mean"]}
    out["returns"] = [r for e in evals for r in e["returns"]]
    out["costs"] = [c for e in evals for c in e["costs"]]
    out["target_return"] = evals[0]["target_return"]
    return out
