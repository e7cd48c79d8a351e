"""Subdominance (seed eq. 1), minimum subdominance (seed eq. 2) and surrogate returns.

Notation: ``F [N, K]`` are the cost features of the N trajectories being scored, ``G [M, K]`` those of the
M demonstrations, ``alpha`` the per-feature sensitivities and ``beta`` the per-feature margins. All costs
are lower-is-better.

Eq. 2 minimises over alpha and beta, but with both free the minimum is trivially 0 (alpha = beta = 0), so,
as in the public code of this family of losses, ``beta`` is a fixed margin and the minimum is taken over
``alpha >= 0`` (optionally capped by ``alpha_max``). The problem separates per row and per feature into
the one-dimensional convex, piecewise-linear ``g(a) = 1/M sum_j [a (x - s_j) + beta]_+`` which
``method="exact"`` minimises exactly and ``method="optax"`` by Adam on ``log a``
(:mod:`minsubdt_jax.subdominance_solvers`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from . import subdominance_solvers as solvers


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
    alpha_max=None,
    leave_one_out: bool = False,
    method: str = "exact",
    l2: float = 0.0,
    steps: int = 500,
    learning_rate: float = 0.1,
) -> MinSubdominance:
    """Minimum subdominance of each row of ``F`` against the demo set ``G`` (seed eq. 2).

    ``value_i = min_{alpha >= 0} 1/|G| sum_j subdom_{alpha, beta}(F_i, G_j)`` with ``beta`` a fixed margin.

    Args:
      F: ``[N, K]`` features of scored trajectories.
      G: ``[M, K]`` features of demonstrations.
      beta: margin, scalar or ``[K]``, every entry > 0.
      alpha_max: optional upper bound on alpha, scalar or ``[K]`` (one per feature, e.g. ``beta / std_k`` so that
        dominating a demo by the margin takes beating it by a standard deviation of that feature).
      leave_one_out: exclude pair ``(i, i)``; requires ``N == M`` (scoring the demo set itself) and M >= 2.
      method: ``"exact"`` — one bisection per row over the running means of the sorted demos;
        ``"optax"`` — Adam (optax) on ``log alpha``, ``steps`` steps. Both read the objective from the demos
        sorted once per feature (``O((N + M) log M)`` resp. ``O(M log M + steps N log M)``) and never build the
        ``[N, M]`` difference matrix (:mod:`minsubdt_jax.subdominance_solvers`).
      l2: ``optax`` only: penalty ``l2 * ||alpha_i||^2`` added to each row's objective (``value`` reports
        the subdominance without the penalty).
      steps, learning_rate: ``optax`` only; ``learning_rate`` is in units of ``log alpha`` (scale-free) and
        decays to 0 by cosine.
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
    amax = np.asarray(np.inf if alpha_max is None else alpha_max, F.dtype)
    if amax.shape not in ((), (K,)) or not np.all(amax > 0):
        raise ValueError(f"alpha_max must be None or > 0, a scalar or one per feature [K]=({K},), got {alpha_max}")
    amax = np.broadcast_to(amax, (K,))  # one signature for every form of the cap: one compile per shape
    if method == "exact":
        if l2:
            raise ValueError("l2 is only supported by method='optax'")
        alpha, per_feature = solvers.exact(F, G, beta, amax, leave_one_out)
    elif method == "optax":
        if steps < 1 or not learning_rate > 0 or l2 < 0:
            raise ValueError("optax needs steps >= 1, learning_rate > 0 and l2 >= 0")
        alpha, per_feature = solvers.optax_adam(F, G, beta, amax, leave_one_out, float(l2), int(steps),
                                                float(learning_rate))
    else:
        raise ValueError(f"method must be 'exact' or 'optax', got {method!r}")
    return MinSubdominance(value=per_feature.sum(-1), alpha=alpha, per_feature=per_feature)


# ---------------------------------------------------------------------------------------------------------
# surrogate rewards and returns (seed, "MinSubDT (Our Formulation)")
# ---------------------------------------------------------------------------------------------------------


def surrogate_rewards(min_subdom, lengths, max_len: int | None = None):
    """Surrogate rewards ``r'_t``: ``-min_subdom`` at each trajectory's last step ``T = length - 1``, else 0.

    Args:
      min_subdom: ``[N]`` minimum subdominance of each trajectory (eq. 2), or ``[N, K]``: one value per metric
        (eq. 2's per-metric terms, ``MinSubdominance.per_feature``), paid alike.
      lengths: ``[N]`` int, number of valid steps of each trajectory (>= 1).
      max_len: padded time length T; defaults to ``max(lengths)``.
    Returns:
      ``[N, T]`` (``[N, T, K]``) rewards, 0 on padding.
    """
    lengths = jnp.asarray(lengths)
    v = jnp.asarray(min_subdom)
    if max_len is None:
        max_len = int(np.max(np.asarray(lengths)))
    last = jnp.arange(max_len)[None, :] == lengths[:, None] - 1
    return jnp.where(last.reshape(last.shape + (1,) * (v.ndim - 1)), -v[:, None], 0.0)


def spread_surrogate_rewards(min_subdom, lengths, max_len: int | None = None):
    """The surrogate reward spread evenly over the trajectory: ``r'_t = -min_subdom / L`` at each of its ``L``
    valid steps, 0 on padding; the episode's undiscounted return is ``-min_subdom``, as with
    :func:`surrogate_rewards`, but a discounted critic sees it at every step rather than ``gamma^(L-1-t)`` of it.

    Args:
      min_subdom: ``[N]`` minimum subdominance of each trajectory (eq. 2).
      lengths: ``[N]`` int, valid steps per trajectory (>= 1).
      max_len: padded time length T; defaults to ``max(lengths)``.
    Returns:
      ``[N, T]`` rewards.
    """
    lengths = jnp.asarray(lengths)
    if max_len is None:
        max_len = int(np.max(np.asarray(lengths)))
    valid = jnp.arange(max_len)[None, :] < lengths[:, None]
    return jnp.where(valid, -jnp.asarray(min_subdom)[:, None] / lengths[:, None], 0.0)


def returns_to_go(rewards, lengths):
    """``R_t = sum_{t' >= t} r_t'`` within each trajectory, 0 on padding.

    Args:
      rewards: ``[N, T]`` per-step rewards (padding ignored), or ``[N, T, K]``: one per cost metric.
      lengths: ``[N]`` valid steps per trajectory.
    Returns:
      ``[N, T]`` (``[N, T, K]``) returns-to-go.
    """
    rewards = jnp.asarray(rewards)
    valid = jnp.arange(rewards.shape[1])[None, :] < jnp.asarray(lengths)[:, None]
    valid = valid.reshape(valid.shape + (1,) * (rewards.ndim - 2))
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
