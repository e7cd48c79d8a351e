"""The data side of a run, in the order data flows: dataset -> cost features -> min-subdominance (eq. 2,
leave-one-out) -> the method's return tokens -> the sampler's device arrays. One typed record comes out."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .config import Config
from .costs import CostMetric, cost_metrics, spearman, trajectory_costs
from .data import DatasetFile, SamplerData, resolve_dataset, sampler_data
from .learned_costs import LearnedCostConfig, LearnedCosts, train_learned_costs
from .methods import Method
from .references import References, references_for
from .subdominance import min_subdominance, returns_to_go
from .targets import episode_labels, preference_target


@dataclass(frozen=True)
class Prepared:
    """Everything training and evaluation need from the data.

    Attributes:
      source: the dataset and its file (path, content hash).
      costs: ``[N, K]`` the demos' cost features on ``metrics`` (evaluation compares rollouts with them).
      metrics: the K cost metrics (``--costs``, or a user's own; :mod:`minsubdt_jax.costs`).
      features: ``[N, K']`` the features min-subdominance used (engineered, or learned for learned costs).
      learned: the learned cost model, for a learned-cost method.
      min_subdominance: ``[N]`` each demo's min-subdominance against the others (eq. 2, leave-one-out).
      sampler: the device arrays the train step samples from (states normalised, return tokens scaled).
      state_mean, state_std: ``[obs]`` state normalisation.
      rtg_scale, target_return: the return tokens' divisor and the evaluation target (unscaled; ``[K]`` for a
        vector method, :mod:`minsubdt_jax.methods`).
      dynamics: the env rules the data is scored and evaluated in.
      references: the normalisation its scores use: the dataset's own where it brings them, else the dynamics'
        (:func:`~minsubdt_jax.references.references_for`).
      preference, preference_labels: for a preference-conditioned method (``Method.preference``) the evaluation's
        preference ``[K]`` (the labels' mean) and each episode's label ``[N, K]``, appended to its states (the
        state normalisation leaves them as they are: mean 0, std 1); else None.
    """

    source: DatasetFile
    costs: np.ndarray
    features: np.ndarray
    learned: LearnedCosts | None
    min_subdominance: np.ndarray
    sampler: SamplerData
    state_mean: np.ndarray
    state_std: np.ndarray
    rtg_scale: float
    target_return: float | np.ndarray
    dynamics: str = "brax"
    metrics: tuple[CostMetric, ...] = ()
    references: References | None = None
    preference: np.ndarray | None = None
    preference_labels: np.ndarray | None = None

    def summary(self, env: str) -> dict:
        """The dataset block of ``results.json``."""
        data, ms = self.source.data, self.min_subdominance
        out = {
            "path": self.source.path, "sha256": self.source.sha256, "timeouts_inferred": self.source.timeouts_inferred,
            "dropped_transitions": self.source.dropped_transitions,
            "episodes": data.num_trajectories, "transitions": data.num_transitions,
            "return_mean": float(data.returns.mean()), "return_std": float(data.returns.std()),
            "normalized_score_mean": float(self.references.normalize(data.returns).mean()),
            "costs_mean": dict(zip((m.name for m in self.metrics), map(float, self.costs.mean(0)))),
            "cost_metrics": [m.record() for m in self.metrics],
            "min_subdominance_mean": float(ms.mean()), "min_subdominance_std": float(ms.std()),
            "spearman_neg_min_subdominance_vs_return": spearman(-ms, data.returns),
            "min_subdominance_features": "learned" if self.learned else "engineered",
            # up to 300 demos' cost features, for the demos-vs-rollouts scatter of experiments/table1.py
            "costs_sample": self.costs[np.sort(np.random.default_rng(0).permutation(len(self.costs))[:300])].tolist(),
        }
        if self.learned:
            # what the learned features learned: each one's rank agreement with each chosen metric, over the demos
            agree = {f"learned_{i}": {m.name: spearman(self.features[:, i], self.costs[:, j])
                                      for j, m in enumerate(self.metrics)} for i in range(self.features.shape[1])}
            out["learned_costs"] = {**self.learned.report, "spearman_with_metrics": agree}
        return out


def load(cfg: Config, verbose: bool = True, physics: str | None = None) -> DatasetFile:
    """``cfg.dataset`` for ``cfg.env``: loaded, or recorded on first use in ``physics`` (default ``cfg.physics``)
    (:func:`~minsubdt_jax.data.resolve_dataset`)."""
    return resolve_dataset(cfg.env, cfg.dataset, transitions=cfg.dataset_transitions, horizon=cfg.episode_length,
                           seed=cfg.dataset_seed, verbose=verbose, physics=physics or cfg.physics)


def prepare(cfg: Config, method: Method, verbose: bool = True, source: DatasetFile | None = None,
            dynamics: str = "brax", metrics=None) -> Prepared:
    """Load (or record) ``cfg.dataset`` for ``cfg.env`` (or take ``source``, already loaded), check it, and build
    ``method``'s training data; ``dynamics`` are the data's (its scores' references). The cost features are
    ``metrics`` (names or :class:`~minsubdt_jax.costs.CostMetric`), else ``cfg.costs``, else the env's default.

    Raises ValueError (before anything is written) on data that cannot be used: see the checks below and
    :func:`~minsubdt_jax.data.resolve_dataset`."""
    source = load(cfg, verbose) if source is None else source
    dataset, path = source.data, source.path
    if dataset.max_len > cfg.episode_length:
        raise ValueError(f"the dataset has episodes of {dataset.max_len} steps, longer than --episode-length "
                         f"{cfg.episode_length}")
    if dataset.num_trajectories < 2:
        raise ValueError(f"{path}: the dataset has {dataset.num_trajectories} episode; min-subdominance scores each "
                         f"demonstration against the others and needs at least 2")
    metrics = cost_metrics(cfg.env, cfg.costs if metrics is None else metrics)
    costs = np.asarray(trajectory_costs(metrics, dataset.observations, dataset.lengths, cfg.episode_length,
                                        terminated=dataset.terminals, actions=dataset.actions))
    with np.errstate(over="ignore", invalid="ignore"):
        mean, std = dataset.state_stats()
    if not (np.isfinite(mean).all() and np.isfinite(std).all()):
        raise ValueError(f"{path}: the observations' mean or standard deviation overflows float32; the states "
                         f"cannot be normalised")
    learned = None
    features = costs
    if method.features == "learned":
        lc_cfg = LearnedCostConfig(cost_dim=cfg.cost_dim, steps=cfg.cost_steps, pairs_per_step=cfg.cost_pairs,
                                   label_noise=cfg.cost_label_noise, seed=cfg.seed)
        learned = train_learned_costs(dataset.observations, dataset.lengths, dataset.returns, lc_cfg,
                                      terminated=dataset.terminals, beta=cfg.beta, horizon=cfg.episode_length,
                                      state_mean=mean, state_std=std)
        features = learned.features(dataset.observations, dataset.lengths, dataset.terminals)
    sub = min_subdominance(features, features, cfg.beta, alpha_max=cfg.alpha_max, leave_one_out=True)
    ms = np.asarray(sub.value)
    rewards = np.asarray(method.rewards(dataset, sub, costs), np.float32)  # [N, T] or, per metric, [N, T, K]
    if method.vector and cfg.target_return is not None:
        raise ValueError(f"--method {method.name} has a target per metric: give it to python -m "
                         f"minsubdt_jax.evaluate RUN_DIR --target, not as --target-return")
    rtg_scale = cfg.rtg_scale or method.scale(rewards.sum(1))
    target = (method.target_return(dataset.returns, costs) if cfg.target_return is None else cfg.target_return)
    rtg = np.asarray(returns_to_go(rewards, dataset.lengths)) / rtg_scale
    if not np.isfinite(rtg).all():
        raise ValueError(f"{path}: the returns-to-go overflow float32 (divided by --rtg-scale {rtg_scale})")
    labels = _preference_labels(source, method, len(metrics)) if method.preference else None
    states, preference = dataset, None
    if labels is not None:  # PEDA's "(P)": each state carries its episode's preference, left unnormalised
        k = labels.shape[1]
        states = dataclasses.replace(dataset, observations=np.concatenate(
            [dataset.observations, np.broadcast_to(labels[:, None], dataset.observations.shape[:2] + (k,))], -1))
        mean, std = np.concatenate([mean, np.zeros(k, np.float32)]), np.concatenate([std, np.ones(k, np.float32)])
        preference = (labels.mean(0) / labels.mean(0).sum()).astype(np.float32)
        if method.vector and cfg.target_return is None:  # the data's episode that serves it best (targets)
            target = preference_target(rtg[:, 0] * rtg_scale, preference, labels)[0]
    prep = Prepared(source=source, costs=costs, features=features, learned=learned, min_subdominance=ms,
                    sampler=sampler_data(states, rtg, mean, std, rewards.reshape(rewards.shape[:2] + (-1,)).sum(-1)
                                         / rtg_scale,
                                         np.ones_like(dataset.terminals) if method.episodic else dataset.terminals),
                    state_mean=mean, state_std=std, rtg_scale=rtg_scale,
                    target_return=target, dynamics=dynamics, metrics=metrics,
                    references=references_for(cfg.env, dynamics, source.references), preference=preference,
                    preference_labels=labels)
    if verbose:
        _report(prep, cfg)
    return prep


def _preference_labels(source: DatasetFile, method: Method, k: int) -> np.ndarray:
    """``[N, K]`` the episodes' preference labels a preference-conditioned method reads; one ValueError where the
    data has none or they weigh another number of objectives than the run's ``k`` cost metrics."""
    labels = episode_labels(source)
    if labels is None:
        raise ValueError(f"--method {method.name} conditions on each episode's preference, and {source.path} has no "
                         f"infos/preference: record a multi-preference dataset (--dataset mo-expert or mo-amateur)")
    if labels.shape[1] != k:
        raise ValueError(f"--method {method.name}: the data's preferences weigh {labels.shape[1]} objectives and the "
                         f"run has {k} cost metrics; choose as many (--costs x_velocity,energy@lived)")
    return labels.astype(np.float32)


def _report(prep: Prepared, cfg: Config) -> None:
    data, ms = prep.source.data, prep.min_subdominance
    print(f"dataset {prep.source.path}: {data.num_trajectories} episodes, {data.num_transitions} transitions, return "
          f"{data.returns.mean():.1f} ± {data.returns.std():.1f}")
    print(f"min-subdominance {ms.mean():.3f} ± {ms.std():.3f}; Spearman(-min-subdominance, true return) = "
          f"{spearman(-ms, data.returns):.3f}", flush=True)
    if prep.learned:
        r = prep.learned.report
        print(f"learned costs (K'={cfg.cost_dim}): held-out pair accuracy {r['heldout_pair_accuracy']:.3f}, "
              f"train {r['train_pair_accuracy']:.3f}", flush=True)
