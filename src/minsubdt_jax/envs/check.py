"""Which dynamics did a dataset come from? Replay its transitions from their recorded physics states.

A transition ``(s_t, a_t, s_{t+1})`` of a file that records the physics state each action was taken in (``infos/qpos``
and ``infos/qvel``: D4RL's v2 files and ours) is replayed in C MuJoCo under each dynamics
(:mod:`minsubdt_jax.envs.rules`): set the state, take ``a_t`` for ``frame_skip`` substeps, observe, and compare with
the recorded ``s_{t+1}``. The dynamics the data came from reproduces it to float rounding (the solver's warm start,
which files do not record, is the one thing replay cannot restore); another dynamics misses by orders of magnitude
more. brax's and gym's models place the root's z joint differently (``qpos0``), so the file's convention is found
first, from the recorded state's own observation.
"""

from __future__ import annotations

import numpy as np

from .c_backend import Sims
from .rules import TORSO, env_rules, forward_position, mj_model, observe, step_outcome
from .spec import env_spec

DEFAULT_TOLERANCE = 1e-3  # largest |Δobs| of a transition counted as reproduced


def replay_errors(env: str, data, qpos, qvel, *, transitions: int = 2000, seed: int = 0) -> dict[str, np.ndarray]:
    """``{dynamics: [m]}``: the largest one-step ``|Δobs|`` of each of ``m`` sampled transitions under each dynamics.

    ``data`` is a :class:`~minsubdt_jax.data.Trajectories`; ``qpos [n, nq]``, ``qvel [n, nv]`` are its flat per-step
    physics states (the state each action was taken in, in the order of ``data.valid_mask()``). At most
    ``transitions`` transitions whose next state is in the file are drawn (``seed``)."""
    obs = np.asarray(data.observations, np.float64)
    act = np.clip(np.asarray(data.actions, np.float64), -1.0, 1.0)
    lengths = np.asarray(data.lengths)
    ep, t = np.nonzero(data.valid_mask())
    qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
    if qpos.shape[0] != ep.size or qvel.shape[0] != ep.size:
        raise ValueError(f"the physics states hold {qpos.shape[0]} rows, the data {ep.size} transitions")
    nq = mj_model(env, next(iter(env_spec(env).dynamics))).nq
    if qpos.shape[1] != nq:
        raise ValueError(f"the recorded qpos has {qpos.shape[1]} entries, {env} has {nq}")
    has_next = np.flatnonzero(t + 1 < lengths[ep])
    if has_next.size == 0:
        raise ValueError("no transition with a recorded next state (every episode has length 1)")
    pick = np.random.default_rng(seed).choice(has_next, min(transitions, has_next.size), replace=False)
    e, s = ep[pick], t[pick]
    q, v, a = qpos[pick], qvel[pick], act[e, s]
    source = _source_convention(env, q, v, obs[e, s])
    return {dyn: np.abs(_step_observe(env, dyn, source, q, v, a) - obs[e, s + 1]).max(axis=1)
            for dyn in env_spec(env).dynamics}


def _step_observe(env: str, dynamics: str, source: str, qpos, qvel, actions) -> np.ndarray:
    """``[n, obs]``: the observation after one step of ``actions [n, act]`` from the states ``qpos, qvel`` (in
    ``source``'s qpos convention) under ``dynamics``, in C MuJoCo."""
    sims = Sims(env, dynamics, len(qpos), threads=0)
    sims.set_state(qpos + mj_model(env, dynamics).qpos0 - mj_model(env, source).qpos0, qvel)
    sims.step(actions)
    return observe(env_rules(env, dynamics), np.array(sims.qpos), np.array(sims.qvel), sims.torso(), np)


def final_observations(env: str, dynamics: str, data, qpos, qvel) -> np.ndarray:
    """``[N, obs]``: each episode's observation after its last action (the T+1-th, which D4RL-layout files do not
    keep), by one step of that action from the recorded last state under ``dynamics``: exact for a file recorded
    in it (:func:`replay_errors` checks how well a dynamics reproduces a file). ``data``, ``qpos``, ``qvel`` as in
    :func:`replay_errors`."""
    lengths = np.asarray(data.lengths)
    last = np.cumsum(lengths) - 1  # the flat row of each episode's last step
    qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
    if qpos.shape[0] != lengths.sum():
        raise ValueError(f"the physics states hold {qpos.shape[0]} rows, the data {lengths.sum()} transitions")
    obs = np.asarray(data.observations, np.float64)[np.arange(len(lengths)), lengths - 1]
    act = np.clip(np.asarray(data.actions, np.float64)[np.arange(len(lengths)), lengths - 1], -1.0, 1.0)
    source = _source_convention(env, qpos[last], qvel[last], obs)
    return _step_observe(env, dynamics, source, qpos[last], qvel[last], act)


NEITHER = "neither"  # dynamics_report's answer for data that no dynamics reproduces


def check_dynamics(env: str, data, qpos, qvel, *, transitions: int = 2000, seed: int = 0) -> dict:
    """``{dynamics name: largest one-step |Δobs|}`` over sampled transitions of ``data`` (a
    :class:`~minsubdt_jax.data.Trajectories`) replayed from their recorded physics states ``qpos``, ``qvel``
    (:func:`replay_errors`; a file's are read by :func:`minsubdt_jax.data.named.file_dynamics`).

    Raises:
      ValueError: states that do not fit the data."""
    return {k: float(v.max()) for k, v in replay_errors(env, data, qpos, qvel, transitions=transitions,
                                                        seed=seed).items()}


def dynamics_report(env: str, data, qpos, qvel, *, transitions: int = 2000, seed: int = 0,
                    tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """The check as the data CLI prints it: per dynamics the largest and median ``|Δobs|`` and the share of
    transitions reproduced within ``tolerance``; ``best``: the dynamics that reproduces most (ties: smaller median),
    or ``"neither"`` where none reproduces half of them (data from other physics, or edited)."""
    errs = replay_errors(env, data, qpos, qvel, transitions=transitions, seed=seed)
    per = {k: {"max": float(e.max()), "median": float(np.median(e)), "reproduced": float(np.mean(e <= tolerance))}
           for k, e in errs.items()}
    best = max(per, key=lambda k: (per[k]["reproduced"], -per[k]["median"]))
    tied = [k for k in per if np.array_equal(errs[k], errs[best])]  # the same model and integrator
    out = {"dynamics": per, "best": best if per[best]["reproduced"] >= 0.5 else NEITHER, "tolerance": tolerance,
           "transitions": int(len(next(iter(errs.values()))))}
    # the same states (gym v4's and v5's hopper and halfcheetah): the terminal steps' rewards decide
    if len(tied) > 1 and out["best"] != NEITHER:
        rewards = terminal_reward_errors(env, data, qpos, qvel, tied)
        if rewards is not None:
            for k, e in rewards.items():
                per[k]["terminal_reward_error"] = e
            out["best"] = min(tied, key=lambda k: (rewards[k], tied.index(k)))
        out["same_states"] = tied
    return out


def terminal_reward_errors(env: str, data, qpos, qvel, dynamics: list[str]) -> dict[str, float] | None:
    """``{dynamics: largest |Δreward|}`` over the terminated episodes' last steps, replayed from their recorded
    states: where two dynamics step the same states (gym v4's and v5's hopper), only the healthy reward of the
    terminal step (v4 pays it, v5 does not) tells them apart. None where no episode terminated."""
    lengths = np.asarray(data.lengths)
    ended = np.flatnonzero(np.asarray(data.terminals))
    if ended.size == 0:
        return None
    rows = (np.cumsum(lengths) - 1)[ended]
    q, v = np.asarray(qpos, np.float64)[rows], np.asarray(qvel, np.float64)[rows]
    a = np.clip(np.asarray(data.actions, np.float64)[ended, lengths[ended] - 1], -1.0, 1.0)
    r = np.asarray(data.rewards, np.float64)[ended, lengths[ended] - 1]
    out = {}
    for dyn in dynamics:
        sims, rules = Sims(env, dyn, len(q), threads=0), env_rules(env, dyn)
        sims.set_state(q, v)
        x_before = forward_position(rules, np.array(sims.qpos), sims.torso())
        sims.step(a)
        reward, _ = step_outcome(rules, x_before, np.array(sims.qpos), np.array(sims.qvel), sims.torso(), a, np)
        out[dyn] = float(np.abs(reward - r).max())
    return out


def _source_convention(env: str, qpos, qvel, obs) -> str:
    """The dynamics whose model the recorded ``qpos`` belongs to: the one whose observation of the recorded state is
    nearest the recorded observation (the models differ in where the root z joint's zero lies)."""
    err = {}
    for dyn in env_spec(env).dynamics:
        sims = Sims(env, dyn, len(qpos), threads=0)
        sims.set_state(qpos, qvel)
        err[dyn] = float(np.median(np.abs(observe(env_rules(env, dyn), qpos, qvel, np.array(sims.xpos[:, TORSO]),
                                                  np).astype(np.float64) - obs).max(axis=1)))
    return min(err, key=err.get)
