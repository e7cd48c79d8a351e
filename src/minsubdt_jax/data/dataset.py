"""Trajectory dataset: padded per-episode arrays, built from (and back to) D4RL's flat layout, validated."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np


class DatasetError(ValueError):
    """A dataset file or array that cannot be used, with the reason."""


@dataclass(frozen=True)
class Trajectories:
    """Episodes padded to a common length ``T`` (host numpy arrays; padding is 0).

    Attributes:
      observations: ``[N, T, obs]`` float32.
      actions: ``[N, T, act]`` float32.
      rewards: ``[N, T]`` float32 true rewards.
      lengths: ``[N]`` int32 valid steps per episode (>= 1).
      terminals: ``[N]`` bool, episode ended by termination (else by time-out or end of data).
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    lengths: np.ndarray
    terminals: np.ndarray

    @property
    def num_trajectories(self) -> int:
        return int(self.lengths.shape[0])

    @property
    def num_transitions(self) -> int:
        return int(self.lengths.sum())

    @property
    def max_len(self) -> int:
        return int(self.observations.shape[1])

    @property
    def obs_dim(self) -> int:
        return int(self.observations.shape[2])

    @property
    def act_dim(self) -> int:
        return int(self.actions.shape[2])

    @property
    def returns(self) -> np.ndarray:
        """``[N]`` undiscounted true return of each episode."""
        return self.rewards.sum(axis=1)

    def valid_mask(self) -> np.ndarray:
        """``[N, T]`` True on real steps."""
        return np.arange(self.max_len)[None, :] < self.lengths[:, None]

    def state_stats(self, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Mean and std ``[obs]`` of the states over all real steps (std floored at ``eps``)."""
        x = self.observations[self.valid_mask()]
        return x.mean(0).astype(np.float32), np.maximum(x.std(0), eps).astype(np.float32)

    def sha256(self) -> str:
        """Content hash of the episodes (their D4RL flat arrays: names, dtypes, shapes and bytes): the identity
        of a dataset that runs record and resumes compare, and the checksum our hdf5 files carry."""
        return checksum(self.to_flat())

    def to_flat(self) -> dict[str, np.ndarray]:
        """D4RL flat layout: ``observations, actions, rewards, terminals, timeouts`` over all real steps."""
        m = self.valid_mask()
        last = np.zeros_like(m)
        last[np.arange(self.num_trajectories), self.lengths - 1] = True
        return {
            "observations": self.observations[m],
            "actions": self.actions[m],
            "rewards": self.rewards[m],
            "terminals": (last & self.terminals[:, None])[m],
            "timeouts": (last & ~self.terminals[:, None])[m],
        }


REQUIRED_KEYS = ("observations", "actions", "rewards", "terminals", "timeouts")


def checksum(arrays: dict[str, np.ndarray]) -> str:
    """sha256 over ``arrays`` in key order: each key's name, dtype, shape and bytes."""
    h = hashlib.sha256()
    for k in sorted(arrays):
        a = np.ascontiguousarray(arrays[k])
        h.update(f"{k}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.data)
    return h.hexdigest()


def infer_timeouts(terminals, horizon: int) -> np.ndarray:
    """Time-outs for a D4RL v0 file, which has ``terminals`` only: every ``horizon``-th step of a run of steps
    without termination (the env's time limit), counted from the last termination."""
    terminals = np.asarray(terminals).astype(bool)
    if horizon < 1:
        raise DatasetError(f"the horizon must be >= 1 to infer time-outs, got {horizon}")
    n = len(terminals)
    start = np.maximum.accumulate(np.where(np.r_[True, terminals[:-1]], np.arange(n), 0))  # step of episode start
    return ((np.arange(n) - start + 1) % horizon == 0) & ~terminals


def from_flat(arrays: dict, source: str = "dataset") -> Trajectories:
    """Split D4RL flat arrays into episodes on ``terminals | timeouts``, after validating them.

    A trailing segment with neither flag (an episode the recording stopped inside) is dropped, as the official
    DT loader does: it neither fell nor reached the time limit, so its return and costs would mislead.

    Raises:
      DatasetError: missing keys, mismatched lengths, wrong ranks or dtypes, values that are not finite once in
        float32 (NaN, inf, or beyond float32's range), flags other than 0/1, or no transitions.
    """
    a = _checked_arrays(arrays, source)
    ends = a["terminals"].astype(bool) | a["timeouts"].astype(bool)
    stops = np.nonzero(ends)[0] + 1
    if len(stops) == 0:
        raise DatasetError(f"{source}: no episode ends: neither 'terminals' nor 'timeouts' is ever set")
    starts = np.concatenate([[0], stops[:-1]])
    lengths = (stops - starts).astype(np.int32)
    T = int(lengths.max())
    idx = starts[:, None] + np.arange(T)[None, :]
    valid = np.arange(T)[None, :] < lengths[:, None]
    idx = np.where(valid, idx, 0)

    def pad(x):
        out = x[idx].astype(np.float32)
        out[~valid] = 0.0
        return out

    data = Trajectories(
        observations=pad(a["observations"]),
        actions=pad(a["actions"]),
        rewards=pad(a["rewards"]),
        lengths=lengths,
        terminals=a["terminals"].astype(bool)[stops - 1],
    )
    with np.errstate(over="ignore", invalid="ignore"):
        bad = np.nonzero(~np.isfinite(data.returns))[0]
    if len(bad):
        raise DatasetError(f"{source}: the returns of {len(bad)} episodes overflow float32 (first {bad[:5].tolist()})")
    return data


def _checked_arrays(arrays: dict, source: str) -> dict:
    """:func:`from_flat`'s checks (its Raises) on the D4RL keys; the arrays, observations/actions/rewards float32."""
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise DatasetError(f"{source}: missing keys {missing}; a D4RL-layout dataset needs {list(REQUIRED_KEYS)}")
    a = {k: np.asarray(arrays[k]) for k in REQUIRED_KEYS}
    not_numeric = {k: str(v.dtype) for k, v in a.items() if not (np.issubdtype(v.dtype, np.number) or v.dtype == bool)}
    if not_numeric:
        raise DatasetError(f"{source}: non-numeric arrays {not_numeric}; expected floats (and 0/1 or bool flags)")
    sizes = {k: v.shape[0] if v.ndim else None for k, v in a.items()}
    if len(set(sizes.values())) != 1:
        raise DatasetError(f"{source}: keys have mismatched lengths {sizes}")
    n = sizes["observations"]
    if n == 0:
        raise DatasetError(f"{source}: the dataset is empty (0 transitions)")
    ranks = {"observations": 2, "actions": 2, "rewards": 1, "terminals": 1, "timeouts": 1}
    bad_rank = {k: a[k].shape for k, r in ranks.items() if a[k].ndim != r}
    if bad_rank:
        raise DatasetError(f"{source}: wrong shapes {bad_rank}; expected observations/actions [n, d] and "
                           f"rewards/terminals/timeouts [n]")
    for k in ("observations", "actions", "rewards"):
        with np.errstate(over="ignore", invalid="ignore"):
            a[k] = a[k].astype(np.float32)  # checked after the conversion: 1e39 is finite in float64, not here
        bad = ~np.isfinite(a[k])
        if bad.any():
            rows = np.nonzero(bad.reshape(n, -1).any(1))[0]
            raise DatasetError(f"{source}: non-finite values in {k!r} as float32 (NaN, inf, or beyond ±3.4e38) at "
                               f"{len(rows)} rows, first {rows[:5].tolist()}")
    for k in ("terminals", "timeouts"):
        bad = (a[k] != 0) & (a[k] != 1)  # NaN compares unequal to both
        if bad.any():
            rows = np.nonzero(bad)[0]
            raise DatasetError(f"{source}: {k!r} must be 0/1 (or bool), got {a[k][rows[0]]!r} at {len(rows)} rows, "
                               f"first {rows[:5].tolist()}")
    return a


def from_padded(observations, actions, rewards, lengths, terminals) -> Trajectories:
    """A :class:`Trajectories` from padded arrays (e.g. a :class:`~minsubdt_jax.envs.Rollout`), padding zeroed."""
    lengths = np.asarray(lengths, np.int32)
    if lengths.size == 0 or lengths.min() < 1:
        raise DatasetError("every trajectory needs at least one step, and there must be at least one")
    T = int(lengths.max())
    valid = np.arange(T)[None, :] < lengths[:, None]

    def cut(x):
        x = np.array(np.asarray(x)[:, :T], np.float32)
        x[~valid] = 0.0
        return x

    return Trajectories(cut(observations), cut(actions), cut(rewards), lengths, np.asarray(terminals, bool))


def concatenate(parts: list[Trajectories]) -> Trajectories:
    """All episodes of ``parts`` in order, padded to the longest."""
    if not parts:
        raise DatasetError("nothing to concatenate")
    cat = lambda name: pad_concat([getattr(p, name) for p in parts])  # noqa: E731
    return Trajectories(cat("observations"), cat("actions"), cat("rewards"), cat("lengths"), cat("terminals"))


def pad_concat(xs) -> np.ndarray:
    """Concatenate per-episode arrays ``[n_i, T_i, ...]`` along episodes, zero-padding time to the longest
    (``[n_i]`` arrays are simply concatenated)."""
    if xs[0].ndim < 2:
        return np.concatenate(xs)
    T = max(x.shape[1] for x in xs)
    return np.concatenate([np.pad(x, [(0, 0), (0, T - x.shape[1])] + [(0, 0)] * (x.ndim - 2)) for x in xs])
