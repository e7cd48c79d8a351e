"""Solvers of minimum subdominance (seed eq. 2) with a fixed margin ``beta``: exact, and optax.

Per row ``x`` of ``F`` and feature k the problem is one-dimensional and convex:

    g(a) = 1/M' sum_j [a (x - s_j) + beta]_+ ,  a >= 0 (<= alpha_max),

over the demo values ``s_j`` of that feature (``M' = M``, or ``M - 1`` with leave-one-out). Both solvers read
``g`` from the same sorted table of the demos: with ``c(a)`` the number of demos ``s_j < x + beta / a`` (the
active hinges) and ``P(c)`` the sum of the ``c`` smallest, ``g(a) = (a (c x - P(c)) + c beta) / M'``, one
binary search per evaluation (``O(log M)``), and its slope is ``(c x - P(c)) / M'``. The ``[N, M]`` difference
matrix is never built.

* :func:`exact` finds the minimiser directly: a bisection over the running means of the sorted demos.
* :func:`optax_adam` minimises ``g`` over ``log a`` with Adam (optax), each (row, feature) its own coordinate.
  In ``log a`` the optimum is reached at the same speed whatever its scale (``a*`` ranges over many orders of
  magnitude: ``a* = beta / gap`` for a demo only slightly worse than the row), and a relative error ``d`` in
  ``a`` costs at most ``beta * |d|`` in value below the optimum and a factor ``e^d`` above it (``g`` is a sum
  of hinges). It also accepts an L2 penalty on ``a``, which the exact solver does not.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax


class SortedDemos(NamedTuple):
    """The demo set, sorted per feature, as seen from the rows ``x [N, K]`` (leave-one-out already applied).

    ``xc`` is ``x`` shifted by the demo mean (sums use shifted values: better rounding; orderings use the raw
    ones, so a demo equal to ``x`` always compares equal). ``prefix(m)`` is the shifted sum of the ``m``
    smallest remaining demos, ``sorted_value(r)`` the r-th smallest remaining demo, ``count_below(t)`` the number
    of remaining demos ``< t``; all take and return ``[N, K]``. ``at_or_below [N, K]`` is the number of remaining
    demos ``<= x`` (counted once: ``g`` reads it at every evaluation)."""

    x: jax.Array
    xc: jax.Array
    m_eff: int
    prefix: Callable
    sorted_value: Callable
    count_below: Callable
    at_or_below: jax.Array

    def g(self, alpha, beta):
        """``[N, K]`` mean subdominance per feature at ``alpha [N, K]`` (the module's ``g``)."""
        safe = jnp.where(alpha > 0, alpha, 1.0)
        # demos <= x are always active; max() keeps them so when x + beta / alpha rounds down to x (counted with
        # <=, not < nextafter(x): XLA's CPU flushes that subnormal to 0 when x = 0)
        active = jnp.maximum(self.count_below(self.x + beta / safe), self.at_or_below)
        c = jnp.where(alpha > 0, active, self.m_eff)
        return jnp.maximum(alpha * (c * self.xc - self.prefix(c)) + c * beta, 0.0) / self.m_eff


def sorted_demos(F, G, leave_one_out: bool) -> SortedDemos:
    """Sort the demos ``G [M, K]`` once per feature (flat, feature-major tables, so every lookup is a 1-D
    gather) for the rows ``F [N, K]``; with ``leave_one_out`` row i's own demo ``G_i`` is removed implicitly."""
    N, K = F.shape
    M = G.shape[0]
    center = jnp.mean(G, axis=0)
    s_km = sort_rows(G.T)  # [K, M]
    s_flat = s_km.reshape(-1)
    sc_km = s_km - center[:, None]
    P_flat = jnp.concatenate([jnp.zeros((K, 1), s_km.dtype), jnp.cumsum(sc_km, axis=1)], axis=1).reshape(-1)
    sc_flat = sc_km.reshape(-1)
    cols = jnp.arange(K, dtype=jnp.int32)[None, :]
    if leave_one_out:
        # rank of row i's own demo among the sorted demos (the first of its ties: removing any one of equal
        # values leaves the same multiset)
        p = _count_below_rows(s_km, G).astype(jnp.int32)
        m_eff = M - 1
    else:
        p = jnp.full((N, K), M, jnp.int32)  # nothing removed
        m_eff = M
    sc_p = sc_flat[cols * M + jnp.minimum(p, M - 1)]  # shifted value of the removed demo (unused when none)

    def prefix(m):
        return jnp.where(m <= p, P_flat[cols * (M + 1) + m], P_flat[cols * (M + 1) + jnp.minimum(m + 1, M)] - sc_p)

    def sorted_value(r):
        return s_flat[cols * M + jnp.minimum(r + (r >= p), M - 1)]

    def count_below(t, side="left"):
        c = _count_below_rows(s_km, t, side)
        return c - (p < c)

    return SortedDemos(F, F - center, m_eff, prefix, sorted_value, count_below, count_below(F, "right"))


@partial(jax.jit, static_argnames="leave_one_out")
def exact(F, G, beta, alpha_max, leave_one_out):
    """``(alpha [N, K], per_feature [N, K])``: the exact minimiser of eq. 2 per row and feature.

    With the remaining demos sorted ``s_0 <= ... <= s_{M'-1}`` and running means ``mu_m``, the slope of ``g``
    while the ``m`` smallest demos are active is ``m (x - mu_m) / M'``. ``mu_m`` is non-decreasing in m, so the
    minimiser is the breakpoint ``a* = beta / (s_{m*-1} - x)`` where ``m*`` is the first m with ``mu_m > x``
    (``a* = 0`` if there is none, i.e. ``x >= mean(s)``). Under a cap it is ``min(a*, alpha_max)`` by convexity.
    """
    t = sorted_demos(F, G, leave_one_out)
    N, K = F.shape
    # bisection for m* = min{m in [1, M'] : mean of the m smallest > x}; M' + 1 when no such m. The m-th
    # smallest demo exceeding x is implied in exact arithmetic; requiring it too (an exact comparison) keeps
    # the predicate monotone and the breakpoint's gap > 0 when rounding puts a running mean of ties above x.
    lo = jnp.zeros((N, K), jnp.int32)
    hi = jnp.full((N, K), t.m_eff + 1, jnp.int32)

    def body(_, lohi):
        lo, hi = lohi
        mid = (lo + hi) // 2
        m = jnp.clip(mid, 1, t.m_eff)
        ok = (mid >= 1) & (mid <= t.m_eff) & (t.prefix(m) > m * t.xc) & (t.sorted_value(m - 1) > t.x)
        return jnp.where(ok, lo, mid), jnp.where(ok, mid, hi)

    lo, hi = jax.lax.fori_loop(0, math.ceil(math.log2(t.m_eff + 2)) + 1, body, (lo, hi))
    has_breakpoint = hi <= t.m_eff
    gap = t.sorted_value(jnp.clip(hi - 1, 0, t.m_eff - 1)) - t.x  # > 0 whenever has_breakpoint
    alpha = jnp.where(has_breakpoint, beta / jnp.where(has_breakpoint, gap, 1.0), 0.0)
    alpha = jnp.minimum(alpha, alpha_max)
    return alpha, t.g(alpha, beta)


@partial(jax.jit, static_argnames=("leave_one_out", "steps", "learning_rate"))
def optax_adam(F, G, beta, alpha_max, leave_one_out, l2, steps, learning_rate):
    """``(alpha [N, K], per_feature [N, K])`` by Adam on ``log alpha`` (module docstring), ``steps`` steps.

    Each (row, feature) starts at ``alpha_0 = beta / mean_j |x - s_j|`` (the breakpoints' natural scale, so
    the start is free of the features' units); the rate ``learning_rate`` (in units of ``log alpha``) decays
    to 0 by cosine; ``log alpha`` is projected onto ``<= log alpha_max``. The objective of a row is
    ``sum_k g_k(alpha_k) + l2 * ||alpha||^2``; ``per_feature`` reports ``g`` without the penalty.
    """
    t = sorted_demos(F, G, leave_one_out)
    below = t.count_below(t.x)  # mean |x - s| = (2 (c x - P(c)) - (M' x - P(M'))) / M' with c = #{s < x}
    mean_abs = (2.0 * (below * t.xc - t.prefix(below)) - (t.m_eff * t.xc - t.prefix(jnp.full_like(below, t.m_eff)))
                ) / t.m_eff
    theta0 = jnp.log(beta) - jnp.log(jnp.where(mean_abs > 0, mean_abs, 1.0))
    # Past the last breakpoint beta / (smallest s_j - x > 0) g is non-decreasing (only demos <= x are active),
    # so the minimum lies below it: project there (a hair above, for rounding). Without a demo above x, g is
    # non-decreasing everywhere (alpha* = 0) and theta only has to go down from theta0.
    at_or_below = t.at_or_below
    has_above = at_or_below < t.m_eff
    gap_min = t.sorted_value(jnp.minimum(at_or_below, t.m_eff - 1)) - t.x
    last = jnp.where(has_above, jnp.log(beta) - jnp.log(jnp.where(has_above, gap_min, 1.0)) + 1e-6, theta0)
    hi = jnp.minimum(last, jnp.log(alpha_max))
    lo = jnp.minimum(theta0, hi) - 80.0  # exp(-80) relative: alpha = 0 within float32 resolution of g

    def objective(theta):  # rows and features are independent: the gradient of the sum is per coordinate
        alpha = jnp.exp(theta)
        return jnp.sum(t.g(alpha, beta)) + l2 * jnp.sum(alpha ** 2)

    # b2 = 0.9: the second moment follows the current slope, which changes by orders of magnitude as the
    # active set of hinges changes along the way (optax's 0.999 remembers the early slopes too long).
    opt = optax.adam(optax.cosine_decay_schedule(learning_rate, steps), b2=0.9)

    def step(carry, _):
        theta, state = carry
        updates, state = opt.update(jax.grad(objective)(theta), state, theta)
        return (jnp.clip(optax.apply_updates(theta, updates), lo, hi), state), None

    theta0 = jnp.clip(theta0, lo, hi)
    (theta, _), _ = jax.lax.scan(step, (theta0, opt.init(theta0)), None, length=steps)
    alpha = jnp.exp(theta)
    return alpha, t.g(alpha, beta)


def _count_below_rows(s_km, q, side="left"):
    """``[N, K]``: for each query ``q[i, k]``, the number of entries of sorted row ``s_km[k]`` below it (``side=
    "right"``: at or below it)."""
    return jax.vmap(lambda row, col: jnp.searchsorted(row, col, side=side), in_axes=(0, 1), out_axes=1)(s_km, q)


def sort_rows(a):
    """Sorts each row of a float32 ``[K, M]`` ascending (NaN-free input).

    Sorts the order-preserving integer image of the floats (flip the 31 low bits of negatives) and maps back:
    XLA's CPU sort has a fast path for a single integer operand with a plain ``<`` comparator, ~8x faster
    than ``jnp.sort``'s NaN-aware float comparator. Exact: the map is a bijection (an involution)."""
    if a.dtype != jnp.float32:
        return jnp.sort(a, axis=1)
    flip = lambda i: i ^ ((i >> 31) & jnp.int32(0x7FFFFFFF))  # noqa: E731
    keys = jax.lax.sort(flip(jax.lax.bitcast_convert_type(a, jnp.int32)), dimension=1)
    return jax.lax.bitcast_convert_type(flip(keys), jnp.float32)
