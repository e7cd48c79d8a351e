"""The methods of the results table, one record each: which agent trains, on which return tokens, how it is
conditioned at evaluation. ``--method NAME`` picks one; adding a method is adding a record here (and, for a new
kind of policy, an agent under :mod:`minsubdt_jax.agents`).

=====================  =====================================================================================
``minsubdt``           MinSubDT, engineered costs: DT on surrogate returns ``-min-subdominance`` (seed eq. 2)
``minsubdt-learned``   MinSubDT, costs learned from preference pairs (seed eq. 3)
``dt``                 Decision Transformer on the dataset's true rewards
``bc``                 behaviour cloning with the DT's architecture and context, every return token 0
``bc-mlp``             behaviour cloning with an MLP on the current state (the classic BC baseline)
=====================  =====================================================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .subdominance import surrogate_rewards


def _surrogate(data, min_subdom):
    return np.asarray(surrogate_rewards(min_subdom, data.lengths, data.max_len))


def _true(data, min_subdom):
    return data.rewards


def _zero(data, min_subdom):
    return np.zeros_like(data.rewards)


@dataclass(frozen=True)
class Method:
    """One method of the table.

    Attributes:
      name: the ``--method`` value and the results-file name part.
      label: the table's column heading.
      agent: the key of the agent that trains it (:data:`minsubdt_jax.agents.AGENTS`).
      features: ``"engineered"`` or ``"learned"`` (eq. 3) cost features, for its min-subdominance.
      rewards: ``(dataset, min_subdominance [N]) -> [N, T]`` per-step rewards whose returns-to-go are its return
        tokens.
      rtg_scale: returns-to-go are divided by this (``--rtg-scale`` overrides).
      target_from_data: evaluation target return: the dataset's best return (else 0; ``--target-return``
        overrides).
      subtract_rewards: at evaluation the return-to-go token falls by each reward received (true returns).
      returns_alias: its value of the older ``--returns`` flag, if it had one.
    """

    name: str
    label: str
    agent: str
    features: str
    rewards: Callable
    rtg_scale: float = 1.0
    target_from_data: bool = False
    subtract_rewards: bool = False
    returns_alias: str | None = None

    def target_return(self, returns) -> float:
        """The default evaluation target for a dataset whose episodes have ``returns [N]``."""
        return float(np.max(returns)) if self.target_from_data else 0.0


METHODS = {m.name: m for m in (
    Method("minsubdt", "MinSubDT (engg. costs)", "dt", "engineered", _surrogate, returns_alias="subdom"),
    Method("minsubdt-learned", "MinSubDT (learned costs)", "dt", "learned", _surrogate, returns_alias="learned"),
    Method("dt", "DT", "dt", "engineered", _true, rtg_scale=1000.0, target_from_data=True, subtract_rewards=True,
           returns_alias="true"),
    Method("bc", "BC (DT architecture)", "dt", "engineered", _zero, returns_alias="none"),
    Method("bc-mlp", "BC (MLP)", "mlp", "engineered", _zero),
)}
RETURNS_ALIASES = {m.returns_alias: m.name for m in METHODS.values() if m.returns_alias}


def get_method(name: str) -> Method:
    """The method called ``name``; one ValueError naming the choices otherwise."""
    if name not in METHODS:
        raise ValueError(f"--method must be one of {list(METHODS)}, got {name!r}")
    return METHODS[name]
