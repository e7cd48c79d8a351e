"""Cost metrics: a registry of per-step costs a user chooses from (``--costs``), their trajectory features, and
their rank agreement with true returns.

A :class:`CostMetric` is a per-step quantity of (observation, action) in the D4RL observation layout, a range
``[lo, hi]`` that maps it linearly into a per-step cost in [0, 1] (clipped; lower is better, or higher for
``higher_is_better``), and a charge for each step a terminated trajectory did not live. :data:`METRICS` holds the
built-ins (:func:`describe_metrics` prints them); each env's default set is the seed's engineered features below.
A user's own metric is a ``CostMetric`` passed to :func:`cost_metrics` (and ``train(..., metrics=...)``).

The default features (seed, "Experiments"):

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

import dataclasses
from dataclasses import dataclass
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .envs import EnvSpec, env_spec


@dataclass(frozen=True)
class CostMetric:
    """One cost metric. ``value(obs [..., obs], act [..., act]) -> [...]`` is its per-step quantity; the per-step
    cost is ``(clip(value, lo, hi) - lo) / (hi - lo)``, or ``(hi - clip(value, lo, hi)) / (hi - lo)`` when
    ``higher_is_better``; a terminated trajectory is charged ``not_lived`` for each step it did not live
    (:func:`horizon_average`). ``uses_actions``: ``value`` reads the action (datasets and rollouts have them)."""

    name: str
    value: Callable
    lo: float
    hi: float
    higher_is_better: bool = False
    not_lived: float | None = 1.0  # None: averaged over the steps lived, a fall not charged (``NAME@lived``)
    uses_actions: bool = False
    meaning: str = ""

    def __post_init__(self):
        if not (isinstance(self.name, str) and self.name and "," not in self.name):
            raise ValueError(f"a cost metric needs a name without commas, got {self.name!r}")
        if not (np.isfinite(self.lo) and np.isfinite(self.hi) and self.lo < self.hi):
            raise ValueError(f"cost metric {self.name!r}: need finite lo < hi, got [{self.lo}, {self.hi}]")
        if self.not_lived is not None and not 0.0 <= self.not_lived <= 1.0:
            raise ValueError(f"cost metric {self.name!r}: not_lived must be in [0, 1] or None, got {self.not_lived}")

    def per_step(self, observations, actions):
        """``[..., obs]``, ``[..., act]`` -> per-step costs ``[...]`` in [0, 1]."""
        v = jnp.clip(jnp.asarray(self.value(observations, actions), jnp.float32), self.lo, self.hi)
        return ((self.hi - v) if self.higher_is_better else (v - self.lo)) / (self.hi - self.lo)

    def record(self) -> dict:
        """What ``results.json`` says of the metric."""
        return {"name": self.name, "lo": self.lo, "hi": self.hi, "higher_is_better": self.higher_is_better,
                "not_lived": self.not_lived, "meaning": self.meaning}


def _x_velocity(s: EnvSpec) -> CostMetric:
    hi = s.speed_hi  # covers random to expert gaits, m/s
    i = s.x_velocity_index
    return CostMetric("x_velocity", lambda o, a: o[..., i], -1.0, hi, higher_is_better=True,
                      meaning=f"forward speed v_x, from -1 (cost 1) to {hi:g} m/s (cost 0)")


def _fall(s: EnvSpec) -> CostMetric:
    if not s.terminates:
        raise ValueError(f"cost metric 'fall' needs an env that terminates (hopper, walker); {s.name} never falls")
    return CostMetric("fall", lambda o, a: jnp.zeros(o.shape[:-1]), 0.0, 1.0,
                      meaning="share of the horizon not lived after a fall: 0 per step lived, 1 per step not lived")


def _energy(s: EnvSpec) -> CostMetric:
    return CostMetric("energy", lambda o, a: jnp.mean(jnp.square(a), axis=-1), 0.0, 1.0, uses_actions=True,
                      meaning="control energy: mean a^2 over the action dimensions (the ctrl-cost term of the reward, "
                              "actions in [-1, 1])")


def _layout(s: EnvSpec, field: str, metric: str) -> int:
    """The observation index ``field`` of ``s`` (:class:`~minsubdt_jax.envs.EnvSpec`) a metric reads; one error where
    the env has none."""
    i = getattr(s, field)
    if i is None:
        raise ValueError(f"cost metric {metric!r} reads the observation's {field.replace('_', ' ')}; {s.name} has none")
    return i


def _height_steadiness(s: EnvSpec) -> CostMetric:
    i = _layout(s, "z_velocity_index", "height_steadiness")
    return CostMetric("height_steadiness", lambda o, a: jnp.abs(o[..., i]), 0.0, 3.0,
                      meaning="torso height held steady: |v_z| of the torso, from 0 to 3 m/s")


def _uprightness(s: EnvSpec) -> CostMetric:
    i = _layout(s, "pitch_index", "uprightness")
    return CostMetric("uprightness", lambda o, a: jnp.abs(o[..., i]), 0.0, 1.0,
                      meaning="torso upright: |pitch angle| of the torso, from 0 to 1 rad")


def _joint_speed(s: EnvSpec) -> CostMetric:
    i, hi = _layout(s, "joint_velocity_start", "joint_speed"), s.joint_speed_hi
    return CostMetric("joint_speed", lambda o, a: jnp.mean(jnp.abs(o[..., i:]), axis=-1), 0.0, hi,
                      meaning=f"smooth joints: mean |angular velocity| of the leg joints, from 0 to {hi:g} rad/s")


def _speed_band(s: EnvSpec, lo: float | None = None, hi: float | None = None) -> CostMetric:
    lo, hi = s.speed_band if lo is None else (lo, hi)
    if not lo < hi:
        raise ValueError(f"cost metric speed_band:{lo:g}:{hi:g}: need LO < HI")
    i, sat = s.x_velocity_index, s.speed_band_sat
    name = "speed_band" if (lo, hi) == s.speed_band else f"speed_band:{lo:g}:{hi:g}"
    return CostMetric(name, lambda o, a: jnp.maximum(jnp.maximum(lo - o[..., i], o[..., i] - hi), 0.0), 0.0, sat,
                      meaning=f"forward speed in a target band: distance of v_x from [{lo:g}, {hi:g}] m/s, 0 inside, "
                              f"1 from {sat:g} m/s outside (speed_band:LO:HI sets the band)")


# name -> factory(env spec, *float parameters) -> CostMetric; a factory raises ValueError where the env cannot have it
METRICS: dict[str, Callable[..., CostMetric]] = {
    "x_velocity": _x_velocity, "fall": _fall, "energy": _energy, "height_steadiness": _height_steadiness,
    "uprightness": _uprightness, "speed_band": _speed_band, "joint_speed": _joint_speed}


def default_costs(env: str) -> tuple[str, ...]:
    """The env's default metrics: x_velocity, and fall where the env terminates (hopper, walker)."""
    return ("x_velocity", "fall") if env_spec(env).terminates else ("x_velocity",)


def metric(env: str, name: str) -> CostMetric:
    """The built-in metric ``name`` (``NAME`` or ``NAME:P1:P2``, e.g. ``speed_band:2:3``) for ``env``; with the
    suffix ``@lived`` (``energy@lived``) averaged over the steps lived, a fall not charged (``fall`` charges it)."""
    name, at, mode = name.strip().partition("@")
    if at:
        if mode != "lived" or name.split(":")[0] == "fall":
            raise ValueError(f"cost metric {name}@{mode!r}: the only suffix is @lived (averaged over the steps lived), "
                             f"and not for fall, which is the charge for the steps not lived")
        m = metric(env, name)
        return dataclasses.replace(m, name=m.name + "@lived", not_lived=None,
                                   meaning=m.meaning + "; averaged over the steps lived, a fall not charged")
    base, *params = name.split(":")
    if base not in METRICS:
        raise ValueError(f"unknown cost metric {name!r}; choose from {sorted(METRICS)}")
    try:
        values = [float(p) for p in params]
    except ValueError:
        raise ValueError(f"cost metric {name!r}: parameters must be numbers") from None
    if values and base != "speed_band":
        raise ValueError(f"cost metric {name!r}: only speed_band takes parameters (speed_band:LO:HI)")
    if base == "speed_band" and len(values) not in (0, 2):
        raise ValueError(f"cost metric {name!r}: speed_band takes two parameters, speed_band:LO:HI (m/s)")
    return METRICS[base](env_spec(env), *values)


def cost_metrics(env: str, costs: str | Sequence[str | CostMetric] | None = None) -> tuple[CostMetric, ...]:
    """The metrics of ``--costs``: ``None`` (the env's default set), a comma-separated string of names, or a
    sequence of names and :class:`CostMetric` (a user's own). Raises ValueError on an unknown name, a metric the
    env cannot compute, a repeated name, or an empty list."""
    items = default_costs(env) if costs is None else costs.split(",") if isinstance(costs, str) else tuple(costs)
    out = tuple(c if isinstance(c, CostMetric) else metric(env, c) for c in items)
    names = [m.name for m in out]
    if not out or len(set(names)) != len(names):
        raise ValueError(f"--costs needs one or more distinct metrics, got {names}")
    return out


def check_costs(env: str, costs: str, flag: str = "--costs") -> tuple[CostMetric, ...]:
    """:func:`cost_metrics` of a ``--costs`` flag, its error prefixed with the flag."""
    try:
        return cost_metrics(env, costs)
    except ValueError as e:
        raise ValueError(f"{flag} {costs}: {e}") from None


def describe_metrics(env: str) -> list[str]:
    """One line per built-in metric ``env`` can compute: its name and meaning."""
    lines = []
    for name in METRICS:
        try:
            lines.append(f"{name}: {metric(env, name).meaning}")
        except ValueError as e:
            lines.append(f"{name}: not for {env} ({e})")
    return lines


def trajectory_costs(metrics: Sequence[CostMetric], observations, lengths, horizon: int = 1000, *, terminated,
                     actions=None):
    """Trajectory cost features ``[N, K]`` in [0, 1], one column per metric in order (module docstring).

    Args:
      metrics: the K metrics (:func:`cost_metrics`).
      observations: ``[N, T, obs]`` padded states (entries past ``lengths`` are ignored); actions ``[N, T, act]``
        (needed by a metric that ``uses_actions``).
      lengths: ``[N]`` valid steps per trajectory, each ``<= horizon``.
      horizon: the episode horizon H over which costs are averaged.
      terminated: ``[N]`` bool, the trajectory ended by termination (a fall), not by a time-out or the data's end.
    """
    obs = jnp.asarray(observations)
    lengths = jnp.asarray(lengths)
    if obs.ndim != 3 or lengths.shape != obs.shape[:1]:
        raise ValueError(f"need observations [N, T, obs] and lengths [N], got {obs.shape} and {lengths.shape}")
    if not isinstance(lengths, jax.core.Tracer) and np.any(np.asarray(lengths) > horizon):
        raise ValueError(f"a trajectory is longer ({int(np.max(np.asarray(lengths)))}) than the horizon {horizon}")
    if actions is None and any(m.uses_actions for m in metrics):
        raise ValueError(f"cost metrics {[m.name for m in metrics if m.uses_actions]} need the actions")
    act = None if actions is None else jnp.asarray(actions)
    per_step = jnp.stack([m.per_step(obs, act) for m in metrics], axis=-1)
    charge = jnp.asarray([np.nan if m.not_lived is None else m.not_lived for m in metrics], per_step.dtype)
    return horizon_average(per_step, lengths, horizon, terminated, charge)


def engineered_costs(env: str, observations, lengths, horizon: int = 1000, *, terminated, actions=None,
                     costs: str | Sequence[str | CostMetric] | None = None):
    """:func:`trajectory_costs` of ``cost_metrics(env, costs)`` (default: the env's engineered features)."""
    return trajectory_costs(cost_metrics(env, costs), observations, lengths, horizon, terminated=terminated,
                            actions=actions)


def horizon_average(per_step, lengths, horizon: int, terminated, charge=1.0):
    """Per-step costs ``[N, T, K]`` in [0, 1] -> ``[N, K]`` trajectory features (module docstring): averaged over
    the horizon with every step not lived charged ``charge`` (``[K]`` or a scalar; 1 = the worst cost) for a
    terminated trajectory ``terminated [N]``, averaged over the steps lived for one cut off, and for every
    trajectory in a metric whose charge is NaN (``@lived``)."""
    valid = (jnp.arange(per_step.shape[1])[None, :] < lengths[:, None])[..., None]
    lived = jnp.sum(jnp.where(valid, per_step, 0.0), axis=1)
    L = lengths[:, None].astype(per_step.dtype)
    fell = jnp.asarray(terminated, bool)[:, None] & ~jnp.isnan(jnp.asarray(charge, per_step.dtype))
    return jnp.where(fell, (lived + charge * horizon - charge * L) / horizon, lived / jnp.maximum(L, 1.0))


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
