"""Normalised scores: ``100 (R - R_random) / (R_expert - R_random)`` with random and expert returns measured in
our MJX environments (1000-step episodes, stochastic policies), committed with the behaviour policies
(``behavior/snapshots/{env}/manifest.json``). D4RL's gym references do not apply to MJX physics
(``docs/FIDELITY.md``)."""

from __future__ import annotations

import numpy as np

from .behavior.snapshots import load_manifest
from .envs import env_spec

REFERENCE_SOURCE = "MJX: uniform-random policy and the committed SAC expert, stochastic, 1000-step episodes"


def reference_returns(env: str) -> tuple[float, float]:
    """``(R_random, R_expert)`` for ``env``, measured in MJX and committed with the behaviour policies."""
    refs = load_manifest(env_spec(env).name)["references"]
    return refs["random"]["return_mean"], refs["expert"]["return_mean"]


def normalized_score(env: str, returns):
    """``100 (R - R_random) / (R_expert - R_random)`` with this env's MJX references (:func:`reference_returns`)."""
    lo, hi = reference_returns(env)
    return 100.0 * (np.asarray(returns, np.float64) - lo) / (hi - lo)
