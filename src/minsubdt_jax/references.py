"""Normalised scores: ``100 (R - R_random) / (R_expert - R_random)``, with the references of the dynamics the
episodes ran in (:mod:`minsubdt_jax.envs.rules`):

* ``brax``: random and expert returns measured in our brax-dynamics envs (1000-step episodes, stochastic policies),
  committed with the behaviour policies (``behavior/snapshots/{env}/manifest.json``). D4RL's references do not apply
  to these envs (``docs/FIDELITY.md``);
* ``d4rl``: D4RL's own references (``d4rl/infos.py``: ``REF_MIN_SCORE`` / ``REF_MAX_SCORE``), for data and
  evaluation in gym's dynamics;
* ``v5``: D4RL's too, unless the dataset brings its own (a Minari dataset's ``ref_min_score`` /
  ``ref_max_score``, which win over the dynamics' wherever a dataset has them: :func:`references_for`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .behavior.snapshots import load_manifest
from .envs import env_spec

REFERENCE_SOURCES = {
    "brax": "MJX: uniform-random policy and the committed SAC expert, stochastic, 1000-step episodes",
    "d4rl": "D4RL's references (d4rl/infos.py REF_MIN_SCORE / REF_MAX_SCORE)",
    "v5": "D4RL's references (d4rl/infos.py REF_MIN_SCORE / REF_MAX_SCORE), for want of the dataset's own",
}


# the one convention of every normalised score here (D4RL's paper tables use it too; its get_normalized_score, and
# Minari's, return the 0-1 fraction)
SCALE = "0-100: 100 (R - R_random) / (R_expert - R_random); D4RL's and Minari's get_normalized_score give this / 100"


def reference_returns(env: str, dynamics: str = "brax") -> tuple[float, float]:
    """``(R_random, R_expert)`` for ``env`` in ``dynamics``."""
    spec = env_spec(env)
    if dynamics in spec.references:  # the env's record: d4rl/infos.py's for D4RL's envs (every dataset of an env)
        return tuple(spec.references[dynamics][:2])
    if dynamics == "v5" and "d4rl" in spec.references:  # gym's v5 envs score on the scale of v4's
        return tuple(spec.references["d4rl"][:2])
    if dynamics != "brax":
        raise ValueError(f"no references for {spec.name} in dynamics {dynamics!r}; it has "
                         f"{sorted(set(spec.references) | {'brax'})}")
    refs = load_manifest(spec.name)["references"]
    return refs["random"]["return_mean"], refs["expert"]["return_mean"]


def reference_source(env: str, dynamics: str = "brax") -> str:
    """Where :func:`reference_returns`' numbers come from: the env record's own words, else the brax manifests'."""
    own = env_spec(env).references.get(dynamics)
    return own[2] if own is not None else REFERENCE_SOURCES.get(dynamics, "")


def normalized_score(env: str, returns, dynamics: str = "brax"):
    """``100 (R - R_random) / (R_expert - R_random)`` with the references of ``dynamics`` (:func:`reference_returns`)."""
    return references_for(env, dynamics).normalize(returns)


@dataclass(frozen=True)
class References:
    """The references one run scores with: ``random`` and ``expert`` returns, where they come from, and the
    dynamics they belong to."""

    random: float
    expert: float
    source: str
    dynamics: str

    def normalize(self, returns):
        return 100.0 * (np.asarray(returns, np.float64) - self.random) / (self.expert - self.random)

    def record(self) -> dict:
        """What ``results.json`` says about them."""
        return {"dynamics": self.dynamics, "random": self.random, "expert": self.expert, "source": self.source,
                "scale": SCALE}


def references_for(env: str, dynamics: str = "brax", own: tuple | None = None) -> References:
    """The references of data in ``dynamics``: the dataset's ``own`` ``(random, expert, source)`` where it brings
    them (a Minari dataset's metadata), else the dynamics' (:func:`reference_returns`)."""
    if own is not None:
        return References(float(own[0]), float(own[1]), own[2], dynamics)
    lo, hi = reference_returns(env, dynamics)
    return References(lo, hi, reference_source(env, dynamics), dynamics)
