"""Subdominance (seed eq. 1), minimum subdominance (seed eq. 2) and surrogate returns.

Notation: ``F [N, K]`` are the cost features of the N trajectories being scored, ``G [M, K]`` those of the
M demonstrations, ``alpha`` the per-feature sensitivities and ``beta`` the per-feature margins. All costs
are lower-is-better.

Eq. 2 minimises over alpha and beta, but with both free the minimum is trivially 0 (alpha = beta = 0), so,
as in the public code of this family of losses, ``beta`` is a fixed margin and the minimum is taken over
``alpha >= 0`` (optionally capped by ``alpha_max``). The problem separates per row and per feature into
the one-dimensional convex, piecewise-linear ``g(a) = 1/M sum_j [a (x - s_j) + beta]_+`` which
``method="exact"`` minimises exactly and ``method="optax"`` by projected Adam.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct


def subdominance(f, f_demo, alpha, beta):
    """Total subdominance of ``f`` against ``f_demo`` (seed eq. 1, summed over features).

    ``sum_k [alpha_k (f_k - f_demo_k) + beta_k]_+``. All arguments broadcast; the last axis is K.

    Args:
      f: ``[..., K]`` cost features of the scored trajectory.
      f_demo: ``[..., K]`` cost features of the demonstration.
      alpha: ``[..., K]`` or scalar sensitivities.
      beta: ``[..., K]`` or scalar margins.
    Returns:
      ``[...]`` total subdominance.
    """
    return jnp.sum(jax.nn.relu(alpha * (f - f_demo) + beta), axis=-1)


def pairwise_subdominance(F, G, alpha, beta):
    """Subdominance of every row of ``F`` against every row of ``G`` (seed eq. 1).

    Args:
      F: ``[N, K]`` features of scored trajectories.
      G: ``[M, K]`` features of demonstrations.
      alpha: ``[K]`` (shared) or ``[N, K]`` (one per scored row).
      beta: scalar or ``[K]``.
    Returns:
      ``[N, M]`` with entry ``(i, j) = subdom(F_i, G_j)``.
    """
    F, G = _check_features(F, G)
    alpha = jnp.asarray(alpha, F.dtype)
    if alpha.shape not in ((F.shape[1],), F.shape):
        raise ValueError(f"alpha must have shape [K]={(F.shape[1],)} or [N, K]={F.shape}, got {alpha.shape}")
    return _pairwise(F, G, jnp.broadcast_to(alpha, F.shape), _as_beta(beta, F.shape[1], F.dtype))


@jax.jit
def _pairwise(F, G, alpha, beta):
    return subdominance(F[:, None, :], G[None, :, :], alpha[:, None, :], beta)


@struct.dataclass
class MinSubdominance:
    """Result of :func:`min_subdominance`.

    Attributes:
      value: ``[N]`` minimum subdominance (seed eq. 2) of each scored row against the demo set.
      alpha: ``[N, K]`` minimising sensitivities (``alpha >= 0``, ``<= alpha_max`` when capped).
      per_feature: ``[N, K]`` the minimised mean subdominance of each feature; ``value`` is its row sum.
    """

    value: jax.Array
    alpha: jax.Array
    per_feature: jax.Array


def min_subdominance(
    F,
    G,
    beta=1.0,
    *,
    alpha_max: float | None = None,
    leave_one_out: bool = False,
    method: str = "exact",
    l2: float = 0.0,
    steps: int = 500,
    learning_rate: float = 0.1,
    chunk_size: int = 256,
) -> MinSubdominance:
    """Minimum subdominance of each row of ``F`` against the demo set ``G`` (seed eq. 2).

    ``value_i = min_{alpha >= 0} 1/|G| sum_j subdom_{alpha, beta}(F_i, G_j)`` with ``beta`` a fixed margin.

    Args:
      F: ``[N, K]`` features of scored trajectories.
      G: ``[M, K]`` features of demonstrations.
      beta: margin, scalar or ``[K]``, every entry > 0.
      alpha_max: optional upper bound on alpha.
      leave_one_out: exclude pair ``(i, i)``; requires ``N == M`` (scoring the demo set itself) and M >= 2.
      method: ``"exact"`` — sort the demos once per feature, then one bisection per row over running means
        (``O((N + M) log M)``, never builds the ``[N, M]`` difference matrix); ``"optax"`` — projected Adam
        on ``alpha`` in chunks of ``chunk_size`` rows (``O(steps * N * M)``).
      l2: ``optax`` only: penalty ``l2 * ||alpha_i||^2`` added to each row's objective (``value`` reports
        the subdominance without the penalty).
      steps, learning_rate, chunk_size: ``optax`` only. ``learning_rate`` is in units of alpha times the
        demo-set standard deviation of the feature (so it is scale-free); it decays to 0 by cosine.
    Returns:
      :class:`MinSubdominance` with ``value [N]``, ``alpha [N, K]``, ``per_feature [N, K]``.
    """
    F, G = _check_features(F, G)
    K = F.shape[1]
    beta = _as_beta(beta, K, F.dtype)
    if leave_one_out:
        if F.shape[0] != G.shape[0]:
            raise ValueError(f"leave_one_out=True needs N == M (scoring the demo set), got N={F.shape[0]}, M={G.shape[0]}")
        if G.shape[0] < 2:
            raise ValueError("leave_one_out=True needs at least 2 demonstrations")
    if alpha_max is not None and not alpha_max > 0:
        raise ValueError(f"alpha_max must be > 0 or None, got {alpha_max}")
    amax = jnp.inf if alpha_max is None else float(alpha_max)
    if method == "exact":
        if l2:
            raise ValueError("l2 is only supported by method='optax'")
        return _exact(F, G, beta, amax, leave_one_out)
    if method == "optax":
        if steps < 1 or chunk_size < 1 or not learning_rate > 0 or l2 < 0:
            raise ValueError("optax needs steps >= 1, chunk_size >= 1, learning_rate > 0 and l2 >= 0")
        return _optax(F, G, beta, amax, leave_one_out, float(l2), int(steps), float(learning_rate), int(chunk_size))
    raise ValueError(f"method must be 'exact' or 'optax', got {method!r}")


# ---------------------------------------------------------------------------------------------------------
# exact solver
# ---------------------------------------------------------------------------------------------------------


@partial(jax.jit, static_argnames="leave_one_out")
def _exact(F, G, beta, alpha_max, leave_one_out):
    """Exact minimiser of eq. 2 per row and feature.

    For one row (value ``x``) and feature, with the demo values sorted ``s_0 <= ... <= s_{M-1}`` and running
    means ``mu_m = (s_0 + ... + s_{m-1}) / m``: the slope of ``g`` while the ``m`` smallest demos are active is
    ``m (x - mu_m) / M``. ``mu_m`` is non-decreasing in m, so the minimiser is the breakpoint
    ``a* = beta / (s_{m*-1} - x)`` where ``m*`` is the first m with ``mu_m > x`` (``a* = 0`` if there is none,
    i.e. ``x >= mean(s)``). Under a cap the minimiser is ``min(a*, alpha_max)`` by convexity. With
    leave-one-out, the row's own demo (rank ``p`` in the sorted order) is removed from ``s`` implicitly.
    """
    N, K = F.shape
    M = G.shape[0]
    # Orderings and ties use the raw values (x, s), so a demo equal to x always compares equal to it. Sums use
    # values shifted by the demo mean (xc, P): better rounding, and a shift leaves every difference unchanged.
    # Per-feature tables are stored flat, feature-major ([K * M]), so every lookup is a 1-D gather.
    center = jnp.mean(G, axis=0)
    x = F  # [N, K]
    xc = F - center
    s_km = _sort_rows(G.T)  # [K, M]
    s_flat = s_km.reshape(-1)  # [K * M] sorted per feature
    sc_km = s_km - center[:, None]
    P_flat = jnp.concatenate([jnp.zeros((K, 1), s_km.dtype), jnp.cumsum(sc_km, axis=1)], axis=1).reshape(-1)
    sc_flat = sc_km.reshape(-1)
    cols = jnp.arange(K, dtype=jnp.int32)[None, :]
    if leave_one_out:
        # rank of row i's own demo G_i among the sorted demos (the first of its ties: removing any one of
        # equal values leaves the same multiset)
        p = _count_below_rows(s_km, G).astype(jnp.int32)
        m_eff = M - 1
    else:
        p = jnp.full((N, K), M, jnp.int32)  # nothing removed
        m_eff = M
    sc_p = sc_flat[cols * M + jnp.minimum(p, M - 1)]  # shifted value of the removed demo (unused when none)

    def prefix(m):  # sum of the m smallest remaining demos, shifted by center, m in [0, m_eff]
        return jnp.where(m <= p, P_flat[cols * (M + 1) + m], P_flat[cols * (M + 1) + jnp.minimum(m + 1, M)] - sc_p)

    def sorted_value(r):  # r-th smallest remaining demo
        return s_flat[cols * M + jnp.minimum(r + (r >= p), M - 1)]

    def count_below(t):  # number of remaining demos < t
        c = _count_below_rows(s_km, t)
        return c - (p < c)

    # bisection for m* = min{m in [1, m_eff] : mean of the m smallest > x}; m_eff + 1 when no such m. The m-th
    # smallest demo exceeding x is implied in exact arithmetic; requiring it too (an exact comparison) keeps
    # the predicate monotone and the breakpoint's gap > 0 when rounding puts a running mean of ties above x.
    lo = jnp.zeros((N, K), jnp.int32)
    hi = jnp.full((N, K), m_eff + 1, jnp.int32)

    def body(_, lohi):
        lo, hi = lohi
        mid = (lo + hi) // 2
        m = jnp.clip(mid, 1, m_eff)
        ok = (mid >= 1) & (mid <= m_eff) & (prefix(m) > m * xc) & (sorted_value(m - 1) > x)
        return jnp.where(ok, lo, mid), jnp.where(ok, mid, hi)

    lo, hi = jax.lax.fori_loop(0, math.ceil(math.log2(m_eff + 2)) + 1, body, (lo, hi))
    has_breakpoint = hi <= m_eff
    gap = sorted_value(jnp.clip(hi - 1, 0, m_eff - 1)) - x  # > 0 whenever has_breakpoint
    alpha = jnp.where(has_breakpoint, beta / jnp.where(has_breakpoint, gap, 1.0), 0.0)
    alpha = jnp.minimum(alpha, alpha_max)
    per_feature = _g_sorted(alpha, x, xc, beta, m_eff, count_below, prefix)
    return MinSubdominance(value=per_feature.sum(-1), alpha=alpha, per_feature=per_feature)


def _count_below_rows(s_km, q):
    """``[N, K]``: for each query ``q[i, k]``, the number of entries of sorted row ``s_km[k]`` below it."""
    return jax.vmap(lambda row, col: jnp.searchsorted(row, col, side="left"), in_axes=(0, 1), out_axes=1)(s_km, q)


def _sort_rows(a):
    """Sorts each row of a float32 ``[K, M]`` ascending (NaN-free input).

    Sorts the order-preserving integer image of the floats (flip the 31 low bits of negatives) and maps back:
    XLA's CPU sort has a fast path for a single integer operand with a plain ``<`` comparator, ~8x faster
    than ``jnp.sort``'s NaN-aware float comparator. Exact: the map is a bijection (an involution)."""
    if a.dtype != jnp.float32:
        return jnp.sort(a, axis=1)
    flip = lambda i: i ^ ((i >> 31) & jnp.int32(0x7FFFFFFF))  # noqa: E731
    keys = jax.lax.sort(flip(jax.lax.bitcast_convert_type(a, jnp.int32)), dimension=1)
    return jax.lax.bitcast_convert_type(flip(keys), jnp.float32)


def _g_sorted(alpha, x, xc, beta, m_eff, count_below, prefix):
    """``g(alpha) = 1/M' sum_j [alpha (x - s_j) + beta]_+`` from sorted demos: the active demos are those
    with ``s_j < x + beta / alpha``, so ``g = (alpha (c x - prefix(c)) + c beta) / M'`` with c their count
    (computed with ``xc`` and ``prefix`` shifted alike)."""
    safe = jnp.where(alpha > 0, alpha, 1.0)
    c = jnp.where(alpha > 0, count_below(x + beta / safe), m_eff)
    return jnp.maximum(alpha * (c * xc - prefix(c)) + c * beta, 0.0) / m_eff


# ---------------------------------------------------------------------------------------------------------
# optax solver
# ---------------------------------------------------------------------------------------------------------


def _optax(F, G, beta, alpha_max, leave_one_out, l2, steps, learning_rate, chunk_size):
    N = F.shape[0]
    chunk = min(chunk_size, N)
    n_chunks = -(-N // chunk)
    pad = n_chunks * chunk - N
    Fp = jnp.pad(F, ((0, pad), (0, 0)))
    alpha = _optax_chunks(Fp.reshape(n_chunks, chunk, -1), G, beta, alpha_max, leave_one_out, l2, steps,
                          learning_rate)
    alpha = alpha.reshape(n_chunks * chunk, -1)[:N]
    per_feature = _mean_subdominance_per_feature(F, G, alpha, beta, leave_one_out, chunk)
    return MinSubdominance(value=per_feature.sum(-1), alpha=alpha, per_feature=per_feature)


@partial(jax.jit, static_argnames=("leave_one_out", "steps", "learning_rate"))
def _optax_chunks(Fc, G, beta, alpha_max, leave_one_out, l2, steps, learning_rate):
    """Projected Adam on ``a = alpha * std_k(G)`` for each chunk of rows ``Fc [C, n, K]`` in turn."""
    n_chunks, n, K = Fc.shape
    M = G.shape[0]
    scale = jnp.std(G, axis=0) + 1e-8  # [K]
    Gs = G / scale
    # b2=0.9: with optax's default 0.999 the second moment remembers the large early gradients (many
    # active hinges) and the steps shrink before alpha reaches large optima; 0.9 tracks the current slope.
    opt = optax.adam(optax.cosine_decay_schedule(learning_rate, steps), b2=0.9)
    a_max = alpha_max * scale

    def solve(args):
        ci, F = args
        D = F[:, None, :] / scale - Gs[None]  # [n, M, K]
        w = jnp.ones((n, M), F.dtype)
        if leave_one_out:
            w = w.at[jnp.arange(n), ci * n + jnp.arange(n)].set(0.0, mode="drop")
        denom = jnp.sum(w, axis=1, keepdims=True)  # [n, 1]

        def objective(a):  # sum over rows of each row's objective: separable, so gradients are per row
            sub = jax.nn.relu(a[:, None, :] * D + beta)  # [n, M, K]
            return jnp.sum(jnp.sum(sub * w[..., None], axis=1) / denom) + l2 * jnp.sum((a / scale) ** 2)

        def step(carry, _):
            a, state = carry
            grads = jax.grad(objective)(a)
            updates, state = opt.update(grads, state, a)
            a = jnp.clip(optax.apply_updates(a, updates), 0.0, a_max)
            return (a, state), None

        a0 = jnp.zeros((n, K), F.dtype)
        (a, _), _ = jax.lax.scan(step, (a0, opt.init(a0)), None, length=steps)
        return a / scale

    return jax.lax.map(solve, (jnp.arange(n_chunks), Fc))


@partial(jax.jit, static_argnames=("leave_one_out", "chunk"))
def _mean_subdominance_per_feature(F, G, alpha, beta, leave_one_out, chunk):
    """``[N, K]``: 1/M' sum_j [alpha_ik (F_ik - G_jk) + beta_k]_+, computed ``chunk`` rows at a time."""
    N, K = F.shape
    M = G.shape[0]
    n_chunks = -(-N // chunk)
    pad = n_chunks * chunk - N
    Fc = jnp.pad(F, ((0, pad), (0, 0))).reshape(n_chunks, chunk, K)
    Ac = jnp.pad(alpha, ((0, pad), (0, 0))).reshape(n_chunks, chunk, K)

    def one(args):
        ci, f, a = args
        sub = jax.nn.relu(a[:, None, :] * (f[:, None, :] - G[None]) + beta)  # [chunk, M, K]
        total = sub.sum(1)
        if leave_one_out:
            own = jnp.clip(ci * chunk + jnp.arange(chunk), 0, M - 1)
            total = total - jax.nn.relu(a * (f - G[own]) + beta)
            return total / (M - 1)
        return total / M

    return jax.lax.map(one, (jnp.arange(n_chunks), Fc, Ac)).reshape(n_chunks * chunk, K)[:N]


# ---------------------------------------------------------------------------------------------------------
# surrogate rewards and returns (seed, "MinSubDT (Our Formulation)")
# ---------------------------------------------------------------------------------------------------------


def surrogate_rewards(min_subdom, lengths, max_len: int | None = None):
    """Surrogate rewards ``r'_t``: ``-min_subdom`` at each trajectory's last step ``T = length - 1``, else 0.

    Args:
      min_subdom: ``[N]`` minimum subdominance of each trajectory (eq. 2).
      lengths: ``[N]`` int, number of valid steps of each trajectory (>= 1).
      max_len: padded time length T; defaults to ``max(lengths)``.
    Returns:
      ``[N, T]`` rewards, 0 on padding.
    """
    lengths = jnp.asarray(lengths)
    if max_len is None:
        max_len = int(np.max(np.asarray(lengths)))
    t = jnp.arange(max_len)[None, :]
    return jnp.where(t == lengths[:, None] - 1, -jnp.asarray(min_subdom)[:, None], 0.0)


def returns_to_go(rewards, lengths):
    """``R_t = sum_{t' >= t} r_t'`` within each trajectory, 0 on padding.

    Args:
      rewards: ``[N, T]`` per-step rewards (padding ignored).
      lengths: ``[N]`` valid steps per trajectory.
    Returns:
      ``[N, T]`` returns-to-go.
    """
    rewards = jnp.asarray(rewards)
    valid = jnp.arange(rewards.shape[1])[None, :] < jnp.asarray(lengths)[:, None]
    r = jnp.where(valid, rewards, 0.0)
    return jnp.where(valid, jnp.flip(jnp.cumsum(jnp.flip(r, 1), axis=1), 1), 0.0)


# ---------------------------------------------------------------------------------------------------------
# input checks
# ---------------------------------------------------------------------------------------------------------


def _check_features(F, G):
    """Checks shapes and casts to a common float dtype; numpy inputs stay numpy (no device round trip)."""
    xp = np if isinstance(F, np.ndarray) and isinstance(G, np.ndarray) else jnp
    F = xp.asarray(F)
    G = xp.asarray(G)
    if F.ndim != 2 or G.ndim != 2 or F.shape[1] != G.shape[1]:
        raise ValueError(f"features must be F [N, K] and G [M, K] with the same K, got {F.shape} and {G.shape}")
    if F.shape[0] == 0 or G.shape[0] == 0 or F.shape[1] == 0:
        raise ValueError(f"features must be non-empty, got F {F.shape} and G {G.shape}")
    dtype = jnp.result_type(F.dtype, G.dtype, jnp.float32)
    F, G = F.astype(dtype), G.astype(dtype)
    if not isinstance(F, jax.core.Tracer) and not isinstance(G, jax.core.Tracer):
        finite = np.isfinite(F).all() and np.isfinite(G).all() if xp is np else _all_finite(F, G)
        if not bool(finite):
            raise ValueError("features must be finite (no NaN or inf)")
    return F, G


@jax.jit
def _all_finite(F, G):
    return jnp.isfinite(F).all() & jnp.isfinite(G).all()


def _as_beta(beta, K, dtype):
    """``[K]`` margins, checked > 0 on the host when concrete (traced margins are not checked)."""
    if isinstance(beta, jax.core.Tracer):
        arr = jnp.asarray(beta, dtype)
    else:
        arr = np.asarray(beta, dtype)
        if arr.shape in ((), (K,)) and not np.all(arr > 0):
            raise ValueError(f"beta (the margin) must be > 0, got {arr}")
    if arr.shape not in ((), (K,)):
        raise ValueError(f"beta must be a scalar or have shape [K]=({K},), got {arr.shape}")
    return jnp.broadcast_to(arr, (K,)) if isinstance(arr, jax.core.Tracer) else np.broadcast_to(arr, (K,))
