"""A trained run's evaluation target as a user gives it (issues 55 and 74): a value per cost metric or one number
(:func:`parse_target`), or a preference over the cost metrics mapped onto the data's own front
(:func:`preference_target`), for ``python -m minsubdt_jax.evaluate`` and ``load_policy``.

A preference ``omega [K]`` (weights over the metrics, summing to 1) picks the data's episode that serves it best, and
the policy is conditioned on that episode's own return token: among the episodes whose preference label is nearest
``omega`` (``infos/preference`` of a multi-preference recording, ``mo-expert``; every episode where the data has no
labels), the one whose ``omega``-weighted per-metric term is least (``minsubdt-vec``: eq. 2's terms against the
demos, ``dt-vec``: its costs). The minimiser of a weighted sum lies on the convex hull of the data's front, so the
target is a point the data reached; this is MODULI's "best return among trajectories of that preference" (ICML 2025)
in the method's own token space. PEDA (Zhu et al. 2023) instead fits preference -> returns with a regression.
"""

from __future__ import annotations

import math
import os

import numpy as np

from .data.d4rl import read_infos


def parse_target(text, method, prep, beta: float, flag: str = "--target"):
    """The return token for ``text`` (``"name=v,name=v"``, a ``{name: v}`` mapping, or one number for a method
    with one return token) under ``method``: ``[K]`` for a vector method (``-v`` per metric, the default where a
    metric is left out), else a float. One ValueError on an unknown metric, a repeated one, a value out of range or
    not a number, naming ``flag`` (the library's ``target`` argument, or the command's ``--target``)."""
    names = [m.name for m in prep.metrics]
    if not method.vector:
        return _number(text, flag)
    if not isinstance(text, dict) and not all("=" in p for p in str(text).split(",")):
        raise ValueError(f"{flag} {text}: {method.name} takes name=value per metric (comma-separated), for some of "
                         f"{names}")
    pairs = list(text.items()) if isinstance(text, dict) else [p.rpartition("=")[::2] for p in str(text).split(",")]
    bound = beta if method.target_bound == "beta" else 1.0
    token = np.array(prep.target_return, np.float32)
    seen = set()
    for name, v in pairs:
        if name not in names or name in seen:
            raise ValueError(f"{flag}: {name!r} is {'repeated' if name in seen else 'not a metric of the run'}; "
                             f"give name=value for some of {names}")
        seen.add(name)
        v = _number(v, f"{flag} {name}")
        if not 0.0 <= v <= bound:
            what = "eq. 2's per-metric term, 0 to the margin beta" if method.target_bound == "beta" else "a cost in [0, 1]"
            raise ValueError(f"{flag} {name}={v:g}: {method.name}'s target is {what} ({bound:g})")
        token[names.index(name)] = -v
    return token


def _number(v, what: str) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: not a number: {v!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{what}: must be finite, got {v!r}")
    return x


def parse_preference(text, names: list[str], flag: str = "--preference") -> np.ndarray:
    """``omega [K]`` from ``text``: ``"name=w,..."`` or a ``{name: w}`` mapping (a metric left out weighs 0), or ``K``
    comma-separated weights in the run's metric order; each finite and >= 0, not all 0; normalised to sum 1. One
    ValueError naming ``flag`` otherwise."""
    if isinstance(text, dict) or "=" in str(text):
        pairs = list(text.items()) if isinstance(text, dict) else [p.rpartition("=")[::2] for p in str(text).split(",")]
        w, seen = np.zeros(len(names)), set()
        for name, v in pairs:
            if name not in names or name in seen:
                raise ValueError(f"{flag}: {name!r} is {'repeated' if name in seen else 'not a metric of the run'}; "
                                 f"give name=weight for some of {names}")
            seen.add(name)
            w[names.index(name)] = _number(v, f"{flag} {name}")
    else:
        parts = str(text).split(",")
        if len(parts) != len(names):
            raise ValueError(f"{flag} {text}: {len(parts)} weight(s) for the run's {len(names)} metrics {names}")
        w = np.array([_number(v, flag) for v in parts])
    if np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"{flag} {text}: the weights must be >= 0 and not all 0")
    return w / w.sum()


def episode_labels(source) -> np.ndarray | None:
    """``[N, K]`` each episode's preference label (``infos/preference`` at its first step) of a
    :class:`~minsubdt_jax.data.DatasetFile`, or None where the data has none (a file without it, a Minari dataset)."""
    path = source.path
    if not (isinstance(path, str) and path.endswith((".hdf5", ".h5")) and os.path.exists(path)):
        return None
    pref = read_infos(path).get("preference")
    if pref is None:
        return None
    starts = np.concatenate([[0], np.cumsum(source.data.lengths)[:-1]]).astype(int)
    return np.asarray(pref)[starts]


def episode_tokens(prep) -> np.ndarray:
    """``[N, K]`` each episode's own return token (its first step's, unscaled) under a vector method's ``prep``."""
    return np.asarray(prep.sampler.returns_to_go)[:, 0] * prep.rtg_scale


def preference_target(tokens: np.ndarray, omega: np.ndarray, labels: np.ndarray | None = None
                      ) -> tuple[np.ndarray, int]:
    """``(token [K], episode)``: of the episodes' return tokens ``tokens [N, K]`` (each minus its per-metric terms),
    the one of the episode that best serves ``omega`` (module docstring), and its index; ``labels``: ``[N, K']`` the
    episodes' preferences, or None."""
    tokens = np.asarray(tokens)
    cand = np.arange(len(tokens))
    if labels is not None:
        if labels.shape[1] != len(omega):
            raise ValueError(f"the data's preference labels weigh {labels.shape[1]} objectives, the run has "
                             f"{len(omega)} cost metrics")
        dist = np.abs(labels - omega).sum(1)
        cand = np.flatnonzero(dist <= dist.min() + 1e-6)
    best = cand[np.argmin(-tokens[cand] @ omega)]
    return tokens[best].astype(np.float32), int(best)


def target_token(method, prep, beta: float, target=None, preference=None, flag: str = "--") -> tuple:
    """``(token, preference)``: the return token a run's model is evaluated at, ``target`` (:func:`parse_target`),
    else ``preference`` (:func:`preference_target`), else the run's own; and the preference ``[K]`` its states carry
    (a preference-conditioned method's: the one given, else the run's own; else None). ``flag`` prefixes the argument
    names in errors (``--`` for the command, ``""`` for the library)."""
    if target is not None and preference is not None:
        raise ValueError(f"give {flag}target or {flag}preference, not both")
    if target is not None:
        return parse_target(target, method, prep, beta, f"{flag}target"), prep.preference
    if preference is None:
        return prep.target_return, prep.preference
    if not (method.vector or method.preference):
        raise ValueError(f"{flag}preference: {method.name} has one return token; a preference needs a token per "
                         f"cost metric (minsubdt-vec, dt-vec) or a preference-conditioned method (bc-p)")
    omega = parse_preference(preference, [m.name for m in prep.metrics], f"{flag}preference")
    labels = prep.preference_labels if prep.preference_labels is not None else episode_labels(prep.source)
    token = preference_target(episode_tokens(prep), omega, labels)[0] if method.vector else prep.target_return
    return token, (omega.astype(np.float32) if method.preference else None)
