"""The methods of the results table, one record each: which agent trains, on which return tokens, how it is
conditioned at evaluation. ``--method NAME`` picks one; adding a method is adding a record here (and, for a new
kind of policy, an agent under :mod:`minsubdt_jax.agents`).

=====================  =====================================================================================
``minsubdt``           MinSubDT, engineered costs: DT on surrogate returns ``-min-subdominance`` (seed eq. 2)
``minsubdt-learned``   MinSubDT, costs learned from preference pairs (seed eq. 3)
``dt``                 Decision Transformer on the dataset's true rewards
``dt-total``           DT whose return token is the episode's true return, constant over the episode (an ablation:
                       MinSubDT's token structure, one label per trajectory, with the true return's ranking)
``dt-tied``            ``dt-total`` whose demos tied at MinSubDT's largest min-subdominance (K * beta: alpha = 0 in
                       every metric) share one label, their mean return (an ablation: MinSubDT's tie, true returns)
``minsubdt-vec``       MinSubDT with a return token per metric: the K terms of eq. 2 (each demo's per-metric
                       minimised subdominance, in [0, beta]), negated, paid at the last step; a target per metric
                       chooses the trade-off at evaluation (``python -m minsubdt_jax.evaluate``)
``dt-vec``             DT whose return token is the trajectory's K cost features, negated, paid at the last step
                       (PEDA's MODT idea, per-objective returns, on our metrics; no subdominance)
``bc``                 behaviour cloning with the DT's architecture and context, every return token 0
``bc-mlp``             behaviour cloning with an MLP on the current state (the classic BC baseline)
``iql``                IQL (Kostrikov et al. 2021) on the true rewards, scaled by 1000 / (max - min return)
``td3bc``              TD3+BC (Fujimoto & Gu 2021) on the true rewards
``cql``                CQL(H) (Kumar et al. 2020) on the true rewards
``minsubdt-iql``       IQL on MinSubDT's surrogate reward (one reward, ``-min-subdominance``, at the last step)
``minsubdt-td3bc``     TD3+BC on the surrogate reward
``minsubdt-iql-spread``  IQL on the surrogate reward spread over the episode: ``-min-subdominance / L`` at each of
                       its L steps (the same undiscounted return; a discounted critic sees it at every step)
``minsubdt-td3bc-spread``  TD3+BC on the spread surrogate reward
``minsubdt-cql``       CQL on the surrogate reward
``brac-v``             BRAC-v (Wu, Tucker & Nachum 2019) on the true rewards
``minsubdt-brac-v``    BRAC-v on the surrogate reward
``bear``               BEAR (Kumar et al. 2019) on the true rewards
``minsubdt-bear``      BEAR on the surrogate reward
``awr``                AWR (Peng et al. 2019), offline, on the true rewards
``minsubdt-awr``       AWR on the surrogate reward
=====================  =====================================================================================

The surrogate reward is a trajectory's: it is paid once, at its last step, and nothing follows it, so for the
critic agents every episode of a ``minsubdt-*`` method ends in a terminal transition (``episodic``), a time-out
too; on the true rewards a time-out bootstraps (D4RL's ``qlearning_dataset``). What a discounted critic makes of
one reward at step T: ``docs/critics.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .subdominance import spread_surrogate_rewards, surrogate_rewards


def _surrogate(data, sub, costs):
    return np.asarray(surrogate_rewards(sub.value, data.lengths, data.max_len))


def _spread(data, sub, costs):
    return np.asarray(spread_surrogate_rewards(sub.value, data.lengths, data.max_len))


def _true(data, sub, costs):
    return data.rewards


def _total(data, sub, costs):
    return np.asarray(surrogate_rewards(-data.returns, data.lengths, data.max_len))


def _per_metric(values):
    """``[N, T, K]``: ``-values [N, K]`` at each trajectory's last step, 0 elsewhere (one reward per metric)."""
    def rewards(data, sub, costs):
        return np.asarray(surrogate_rewards(np.asarray(values(sub, costs), np.float32), data.lengths, data.max_len))
    return rewards


def _tied(data, sub, costs):
    ms = np.asarray(sub.value)
    tied = ms >= ms.max() - 1e-5  # the demos at the largest min-subdominance, K * beta when any is tied (eq. 2)
    labels = np.where(tied, np.mean(data.returns[tied]), data.returns)
    return np.asarray(surrogate_rewards(-labels, data.lengths, data.max_len))


def _zero(data, sub, costs):
    return np.zeros_like(data.rewards)


@dataclass(frozen=True)
class Method:
    """One method of the table.

    Attributes:
      name: the ``--method`` value and the results-file name part.
      label: the table's column heading.
      agent: the key of the agent that trains it (:data:`minsubdt_jax.agents.AGENTS`).
      features: ``"engineered"`` or ``"learned"`` (eq. 3) cost features, for its min-subdominance.
      rewards: ``(dataset, MinSubdominance, costs [N, K]) -> [N, T]`` per-step rewards whose returns-to-go are its
        return tokens (``[N, T, K]`` for a ``vector`` method: one per cost metric).
      rtg_scale: returns-to-go (and the critics' rewards) are divided by this (``--rtg-scale`` overrides); None:
        by (max - min episode return) / 1000 of the dataset, IQL's reward normalisation.
      target_from_data: evaluation target return: the dataset's best return (else 0; ``--target-return``
        overrides).
      subtract_rewards: at evaluation the return-to-go token falls by each reward received (true returns).
      returns_alias: its value of the older ``--returns`` flag, if it had one.
      episodic: for critic agents, every episode's last step is a terminal transition (else only terminations').
      vector: the return token is a K-vector, one entry per cost metric (a DT agent's only); its evaluation target
        is a vector too, each entry in ``[0, target_bound]`` (0: the best), the token its negation.
      target_bound: ``"beta"`` (eq. 2's per-metric term is at most the margin) or ``"cost"`` (a cost, at most 1).
      preference: each state carries its episode's preference label ``[K]`` (``infos/preference`` of a
        multi-preference recording, ``mo-expert``), PEDA's "(P)" conditioning (Zhu et al. 2023; PEDA appends it to
        the return and action tokens too, we to the state alone); evaluated at a preference
        (:mod:`minsubdt_jax.targets`).
    """

    name: str
    label: str
    agent: str
    features: str
    rewards: Callable
    rtg_scale: float | None = 1.0
    target_from_data: bool = False
    subtract_rewards: bool = False
    returns_alias: str | None = None
    episodic: bool = False
    vector: bool = False
    target_bound: str = "beta"
    preference: bool = False

    def scale(self, returns) -> float:
        """The divisor of the return tokens and rewards for a dataset whose episodes have ``returns [N]`` (of this
        method's rewards)."""
        if self.rtg_scale is not None:
            return self.rtg_scale
        spread = float(np.max(returns) - np.min(returns))
        if not spread > 0:
            raise ValueError(f"--method {self.name} scales rewards by 1000 / (max - min episode return), and every "
                             f"episode has the return {float(np.max(returns)):g}; give --rtg-scale")
        return spread / 1000.0

    def target_return(self, returns, costs=None):
        """The default evaluation target for a dataset whose episodes have ``returns [N]``; for a vector method,
        ``[K]`` from the demos' ``costs [N, K]``: the token of eq. 2's 0 in every metric (beat every demo), or for
        per-metric costs the best demo's cost in each metric (the data's ideal point), negated."""
        if self.vector:
            k = np.shape(costs)[1]
            return -np.min(costs, 0).astype(np.float32) if self.target_from_data else np.zeros(k, np.float32)
        return float(np.max(returns)) if self.target_from_data else 0.0


METHODS = {m.name: m for m in (
    Method("minsubdt", "MinSubDT (engg. costs)", "dt", "engineered", _surrogate, returns_alias="subdom"),
    Method("minsubdt-learned", "MinSubDT (learned costs)", "dt", "learned", _surrogate, returns_alias="learned"),
    Method("dt", "DT", "dt", "engineered", _true, rtg_scale=1000.0, target_from_data=True, subtract_rewards=True,
           returns_alias="true"),
    Method("dt-total", "DT (episode return, constant token)", "dt", "engineered", _total, rtg_scale=1000.0,
           target_from_data=True),
    Method("dt-tied", "DT (episode return, MinSubDT's tie)", "dt", "engineered", _tied, rtg_scale=1000.0,
           target_from_data=True),
    Method("minsubdt-vec", "MinSubDT (a token per metric)", "dt", "engineered",
           _per_metric(lambda sub, costs: sub.per_feature), vector=True),
    Method("dt-vec", "DT (a cost token per metric)", "dt", "engineered", _per_metric(lambda sub, costs: costs),
           target_from_data=True, vector=True, target_bound="cost"),
    Method("modt-p", "MODT(P) (PEDA)", "dt", "engineered", _per_metric(lambda sub, costs: costs),
           target_from_data=True, vector=True, target_bound="cost", preference=True),
    Method("morvs-p", "MORvS(P) (PEDA)", "mlp", "engineered", _per_metric(lambda sub, costs: costs),
           target_from_data=True, vector=True, target_bound="cost", preference=True),
    Method("bc-p", "BC(P) (PEDA)", "mlp", "engineered", _zero, preference=True),
    Method("bc", "BC (DT architecture)", "dt", "engineered", _zero, returns_alias="none"),
    Method("bc-mlp", "BC (MLP)", "mlp", "engineered", _zero),
    Method("iql", "IQL", "iql", "engineered", _true, rtg_scale=None),
    Method("td3bc", "TD3+BC", "td3bc", "engineered", _true),
    Method("cql", "CQL", "cql", "engineered", _true),
    Method("minsubdt-iql", "MinSubDT-IQL", "iql", "engineered", _surrogate, rtg_scale=None, episodic=True),
    Method("minsubdt-td3bc", "MinSubDT-TD3+BC", "td3bc", "engineered", _surrogate, episodic=True),
    Method("minsubdt-iql-spread", "MinSubDT-IQL (spread)", "iql", "engineered", _spread, rtg_scale=None,
           episodic=True),
    Method("minsubdt-td3bc-spread", "MinSubDT-TD3+BC (spread)", "td3bc", "engineered", _spread, episodic=True),
    Method("minsubdt-cql", "MinSubDT-CQL", "cql", "engineered", _surrogate, episodic=True),
    Method("brac-v", "BRAC-v", "brac", "engineered", _true),
    Method("minsubdt-brac-v", "MinSubDT-BRAC-v", "brac", "engineered", _surrogate, episodic=True),
    Method("bear", "BEAR", "bear", "engineered", _true),
    Method("minsubdt-bear", "MinSubDT-BEAR", "bear", "engineered", _surrogate, episodic=True),
    Method("awr", "AWR", "awr", "engineered", _true),
    Method("minsubdt-awr", "MinSubDT-AWR", "awr", "engineered", _surrogate, episodic=True),
)}
RETURNS_ALIASES = {m.returns_alias: m.name for m in METHODS.values() if m.returns_alias}


def get_method(name: str) -> Method:
    """The method called ``name``; one ValueError naming the choices otherwise."""
    if name not in METHODS:
        raise ValueError(f"--method must be one of {list(METHODS)}, got {name!r}")
    return METHODS[name]
