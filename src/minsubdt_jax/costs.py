"""Engineered trajectory cost metrics (seed, "Experiments") and their rank agreement with true returns.

The seed uses x-velocity for HalfCheetah and x- and z-velocities for Hopper and Walker, "monotonically
transformed into cost metrics". Our transform, per feature k with velocity ``v_k(t)`` read from the state:

    c_k(t) = (hi_k - clip(v_k(t), lo_k, hi_k)) / (hi_k - lo_k)        in [0, 1], decreasing in v_k
    f_k(xi) = 1/H * ( sum_{t < L} c_k(t) + (H - L) * 1 )      if xi terminated (fell)
    f_k(xi) = 1/L *   sum_{t < L} c_k(t)                       if it was cut off (time-out, end of data)

``H`` is the episode horizon (1000) and ``L`` the trajectory's length: the steps a terminated trajectory did not
live are charged the worst per-step cost (1), so falling over early never looks cheap; a trajectory cut off
before the horizon without falling is charged for what it did, not for the steps it was not given. Both features are
lower-is-better and lie in [0, 1]. For the z-velocity feature note that, along any periodic gait, the mean
z-velocity is near 0 (c ~ 0.5), so in practice it charges mostly for the horizon not lived.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .envs import env_spec


@dataclass(frozen=True)
class CostSpec:
    """Velocity features of one env: observation indices and the clip range ``[lo, hi]`` of each."""

    names: tuple[str, ...]
    obs_index: tuple[int, ...]
    lo: tuple[float, ...]
    hi: tuple[float, ...]

    @property
    def dim(self) -> int:
        return len(self.names)


def engineered_spec(env: str) -> CostSpec:
    """Cost features of ``env``: x-velocity (all), z-velocity (hopper, walker). Clip ranges cover the speeds
    of random to expert gaits (m/s)."""
    spec = env_spec(env)
    x_hi = {"hopper": 4.0, "walker": 6.0, "halfcheetah": 15.0}[spec.name]
    if spec.z_velocity_index is None:
        return CostSpec(("x_velocity",), (spec.x_velocity_index,), (-1.0,), (x_hi,))
    return CostSpec(("x_velocity", "z_velocity"), (spec.x_velocity_index, spec.z_velocity_index), (-1.0, -2.0),
                    (x_hi, 2.0))


def engineered_costs(env: str, observations, lengths, horizon: int = 1000, *, terminated):
    """Trajectory cost features ``f(xi)`` (see module docstring).

    Args:
      env: env name.
      observations: ``[N, T, obs]`` padded states (entries past ``lengths`` are ignored).
      lengths: ``[N]`` valid steps per trajectory, each ``<= horizon``.
      horizon: the episode horizon H over which costs are averaged.
      terminated: ``[N]`` bool, the trajectory ended by termination (a fall), not by a time-out or the data's end.
    Returns:
      ``[N, K]`` non-negative, lower-is-better costs in [0, 1].
    """
    cs = engineered_spec(env)
    obs = jnp.asarray(observations)
    lengths = jnp.asarray(lengths)
    if obs.ndim != 3 or lengths.shape != obs.shape[:1]:
        raise ValueError(f"need observations [N, T, obs] and lengths [N], got {obs.shape} and {lengths.shape}")
    if not isinstance(lengths, jax.core.Tracer) and np.any(np.asarray(lengths) > horizon):
        raise ValueError(f"a trajectory is longer ({int(np.max(np.asarray(lengths)))}) than the horizon {horizon}")
    v = obs[..., list(cs.obs_index)]  # [N, T, K]
    lo, hi = jnp.asarray(cs.lo), jnp.asarray(cs.hi)
    return horizon_average((hi - jnp.clip(v, lo, hi)) / (hi - lo), lengths, horizon, terminated)


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
