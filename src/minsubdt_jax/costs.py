"""Engineered trajectory cost metrics (seed, "Experiments") and their rank agreement with true returns.

The seed uses x-velocity for HalfCheetah and x- and z-velocities for Hopper and Walker, "monotonically
transformed into cost metrics". Our features, each lower-is-better and in [0, 1]:

``x_velocity`` (all envs), with per-step cost ``c(t) = (hi - clip(v_x(t), lo, hi)) / (hi - lo)``:

    f_x(xi) = 1/H * ( sum_{t < L} c(t) + (H - L) * 1 )      if xi terminated (fell)
    f_x(xi) = 1/L *   sum_{t < L} c(t)                       if it was cut off (time-out, end of data)

``fall`` (hopper, walker: the envs that terminate), the z-velocity feature reduced to what it measures:

    f_fall(xi) = (H - L) / H   if xi terminated,   0 if it was cut off

``H`` is the episode horizon (1000) and ``L`` the trajectory's length. A terminated trajectory is charged the worst
per-step cost for every step it did not live, so falling early never looks cheap; one cut off before the horizon
is charged for what it did, not for the steps it was not given.

Why ``fall`` and not a z-velocity: along any gait the mean vertical velocity is ~0, so a cost of the signed
z-velocity is constant up to noise over the steps lived and carries information only through the horizon not
lived. Min-subdominance is scale-free in each feature (alpha >= 0 is free), so that
noise counted as much as x: among episodes that never fell its part of min-subdominance correlated with the return
at -0.46 (hopper medium-expert), and the total's Spearman with the return fell from 1.00 (x alone) to 0.43. Every
per-step transform of v_z tried (signed, ``|v_z|`` as a cost or as a reward, with and without a cap
``alpha <= beta/std``) ranked the never-fell episodes worse than x alone on walker medium or hopper
medium-expert. With ``fall`` the total ranks as well as x alone or better on all six hopper/walker datasets
(never-fell episodes rank exactly as with x alone: tested), and its part of min-subdominance correlates with the
return at +0.74 to +0.92 (``experiments/results/cost_features.md``, ``python experiments/cost_features.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .envs import env_spec


@dataclass(frozen=True)
class CostSpec:
    """Cost features of one env: the velocity features (observation index and clip range ``[lo, hi]`` of each),
    then, if ``fall``, the fall feature."""

    velocity_names: tuple[str, ...]
    obs_index: tuple[int, ...]
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    fall: bool

    @property
    def names(self) -> tuple[str, ...]:
        return self.velocity_names + (("fall",) if self.fall else ())

    @property
    def dim(self) -> int:
        return len(self.names)


def engineered_spec(env: str) -> CostSpec:
    """Cost features of ``env``: x-velocity (all; the clip range covers random to expert gaits, m/s) and, for the
    envs that terminate (hopper, walker), the fall feature."""
    spec = env_spec(env)
    x_hi = {"hopper": 4.0, "walker": 6.0, "halfcheetah": 15.0}[spec.name]
    return CostSpec(("x_velocity",), (spec.x_velocity_index,), (-1.0,), (x_hi,), fall=spec.terminates)


def engineered_costs(env: str, observations, lengths, horizon: int = 1000, *, terminated):
    """Trajectory cost features ``f(xi)`` (see module docstring).

    Args:
      env: env name.
      observations: ``[N, T, obs]`` padded states (entries past ``lengths`` are ignored).
      lengths: ``[N]`` valid steps per trajectory, each ``<= horizon``.
      horizon: the episode horizon H over which costs are averaged.
      terminated: ``[N]`` bool, the trajectory ended by termination (a fall), not by a time-out or the data's end.
    Returns:
      ``[N, K]`` non-negative, lower-is-better costs in [0, 1], in the order of ``engineered_spec(env).names``.
    """
    cs = engineered_spec(env)
    obs = jnp.asarray(observations)
    lengths = jnp.asarray(lengths)
    if obs.ndim != 3 or lengths.shape != obs.shape[:1]:
        raise ValueError(f"need observations [N, T, obs] and lengths [N], got {obs.shape} and {lengths.shape}")
    if not isinstance(lengths, jax.core.Tracer) and np.any(np.asarray(lengths) > horizon):
        raise ValueError(f"a trajectory is longer ({int(np.max(np.asarray(lengths)))}) than the horizon {horizon}")
    v = obs[..., list(cs.obs_index)]  # [N, T, Kv]
    lo, hi = jnp.asarray(cs.lo), jnp.asarray(cs.hi)
    per_step = (hi - jnp.clip(v, lo, hi)) / (hi - lo)
    if cs.fall:  # per-step cost 0 while upright: only the steps not lived count
        per_step = jnp.concatenate([per_step, jnp.zeros_like(per_step[..., :1])], axis=-1)
    return horizon_average(per_step, lengths, horizon, terminated)


def horizon_average(per_step, lengths, horizon: int, terminated):
    """Per-step costs ``[N, T, K]`` in [0, 1] -> ``[N, K]`` trajectory features (module docstring): averaged over
    the horizon with every step not lived charged the worst cost 1 for a terminated trajectory ``terminated
    [N]``, averaged over the steps lived for one cut off."""
    valid = (jnp.arange(per_step.shape[1])[None, :] < lengths[:, None])[..., None]
    lived = jnp.sum(jnp.where(valid, per_step, 0.0), axis=1)
    L = lengths[:, None].astype(per_step.dtype)
    fell = jnp.asarray(terminated, bool)[:, None]
    return jnp.where(fell, (lived + horizon - L) / horizon, lived / jnp.maximum(L, 1.0))


def spearman(a, b) -> float:
    """Spearman rank correlation of two ``[N]`` arrays (average ranks for ties); nan if either is constant."""
    ra, rb = _rank(np.asarray(a, np.float64)), _rank(np.asarray(b, np.float64))
    if ra.std() == 0 or rb.std() == 0:
        return float("nan")
    return float(np.corrcoef(ra, rb)[0, 1])


def _rank(x):
    order = np.argsort(x, kind="stable")
    ranks = np.empty(len(x))
    ranks[order] = np.arange(len(x))
    _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    sums = np.bincount(inverse, weights=ranks)
    return sums[inverse] / counts[inverse]
