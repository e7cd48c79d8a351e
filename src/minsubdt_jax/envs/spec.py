"""What every physics backend shares: env specs, the data check, the :class:`Rollout` record and the policy
signature."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import jax
import numpy as np
from flax import struct


@dataclass(frozen=True)
class EnvSpec:
    """Static facts about one environment.

    ``x_velocity_index`` / ``z_velocity_index`` index the observation vector (gym/D4RL layout: ``qpos[1:]``
    then ``qvel``), so cost metrics can be read from any D4RL-layout dataset as well as from our rollouts.
    ``reset_obs0`` is ``obs[0]`` in a reset state (torso height for hopper and walker, the root's z offset for
    halfcheetah), in brax MJX and in gym alike: it tells apart datasets of envs with the same shapes.

    The rest is what other layers tune per env, kept here so an env is described in one place: ``terminates``
    (episodes end when the body falls), the cost metrics' ranges (``speed_hi``: the forward speed of cost 0, m/s;
    ``joint_speed_hi``, rad/s; ``speed_band`` and its saturation ``speed_band_sat``, m/s), D4RL's medium-replay size
    (``replay_transitions``), D4RL's reference returns (``d4rl_random``, ``d4rl_expert``: d4rl/infos.py) and BEAR's
    MMD kernel (``bear_kernel``: its reference's choice per env).
    """

    name: str
    brax_name: str
    obs_dim: int
    act_dim: int
    x_velocity_index: int
    z_velocity_index: int | None
    reset_obs0: float
    terminates: bool
    speed_hi: float
    joint_speed_hi: float
    speed_band: tuple[float, float]
    speed_band_sat: float
    replay_transitions: int
    d4rl_random: float
    d4rl_expert: float
    bear_kernel: str


# reset_obs0 measured as the mean obs[0] of 64 brax MJX resets: 1.25 ± 0.003 (hopper, walker), 0.00 ± 0.06
# (halfcheetah); gym's resets (D4RL) have the same values.
ENVS = {
    "hopper": EnvSpec("hopper", "hopper", 11, 3, 5, 6, 1.25, terminates=True, speed_hi=4.0, joint_speed_hi=10.0,
                      speed_band=(2.0, 3.0), speed_band_sat=2.0, replay_transitions=402_000, d4rl_random=-20.272305,
                      d4rl_expert=3234.3, bear_kernel="laplacian"),
    "walker": EnvSpec("walker", "walker2d", 17, 6, 8, 9, 1.25, terminates=True, speed_hi=6.0, joint_speed_hi=10.0,
                      speed_band=(2.5, 3.5), speed_band_sat=2.0, replay_transitions=302_000, d4rl_random=1.629008,
                      d4rl_expert=4592.3, bear_kernel="laplacian"),
    "halfcheetah": EnvSpec("halfcheetah", "halfcheetah", 17, 6, 8, None, 0.0, terminates=False, speed_hi=15.0,
                           joint_speed_hi=30.0, speed_band=(4.0, 6.0), speed_band_sat=5.0, replay_transitions=202_000,
                           d4rl_random=-280.178953, d4rl_expert=12135.0, bear_kernel="gaussian"),
}
_ALIASES = {"walker2d": "walker", "half_cheetah": "halfcheetah", "cheetah": "halfcheetah"}

def env_spec(name: str) -> EnvSpec:
    """The :class:`EnvSpec` for ``hopper``, ``walker`` (``walker2d``) or ``halfcheetah``."""
    key = _ALIASES.get(name, name)
    if key not in ENVS:
        raise ValueError(f"unknown env {name!r}; choose one of {sorted(ENVS)} (aliases: {sorted(_ALIASES)})")
    return ENVS[key]


def check_dataset(env: str, observations, actions, lengths, recorded_env: str | None = None) -> None:
    """Raise ValueError unless episodes ``observations [N, T, obs]``, ``actions [N, T, act]`` can come from ``env``.

    The shapes must be the env's. Where several envs share them (walker and halfcheetah), the episodes' first
    states must be nearer this env's reset state than another's (median ``obs[0]`` against ``reset_obs0``).
    ``recorded_env`` (the env a file of ours names) must be ``env``, and the actions within the env's bounds
    [-1, 1] (the envs clip to them)."""
    spec = env_spec(env)
    if recorded_env is not None and env_spec(recorded_env) != spec:
        raise ValueError(f"the dataset was recorded in {recorded_env}, not in {spec.name}: pass --env {recorded_env}")
    shape = (observations.shape[-1], actions.shape[-1])
    if shape != (spec.obs_dim, spec.act_dim):
        fits = [s.name for s in ENVS.values() if (s.obs_dim, s.act_dim) == shape]
        raise ValueError(f"the dataset has observations of size {shape[0]} and actions of size {shape[1]}; {spec.name} "
                         f"has {spec.obs_dim} and {spec.act_dim}" + (f" (it fits {', '.join(fits)})" if fits else ""))
    largest = float(np.max(np.abs(np.asarray(actions)))) if np.asarray(actions).size else 0.0
    if largest > 1.0 + 1e-4:  # the envs clip every action to [-1, 1]: such data was not acted in them
        raise ValueError(f"the dataset's actions lie outside {spec.name}'s action bounds [-1, 1] (largest |a| "
                         f"{largest:.4g}): they cannot come from the env; clip or rescale them to [-1, 1] first")
    start = float(np.median(np.asarray(observations)[np.asarray(lengths) > 0, 0, 0]))
    same = [s for s in ENVS.values() if (s.obs_dim, s.act_dim) == shape]
    nearest = min(same, key=lambda s: abs(start - s.reset_obs0))
    if nearest != spec:
        raise ValueError(f"the dataset's episodes start at obs[0] = {start:.3f} (median), a {nearest.name} reset state "
                         f"({nearest.reset_obs0}), not a {spec.name} one ({spec.reset_obs0}): is it a {nearest.name} "
                         f"dataset? (pass --env {nearest.name})")


@struct.dataclass
class Rollout:
    """Recorded episodes, padded to ``horizon`` (entries past ``lengths`` are 0).

    observations ``[N, H, obs]`` (the state each action was taken in), actions ``[N, H, act]``,
    rewards ``[N, H]``, lengths ``[N]``, terminated ``[N]`` (ended by termination, not by time-out),
    and the physics state each action was taken in: qpos ``[N, H, nq]``, qvel ``[N, H, nv]``.
    """

    observations: jax.Array
    actions: jax.Array
    rewards: jax.Array
    lengths: jax.Array
    terminated: jax.Array
    qpos: jax.Array
    qvel: jax.Array


# policy(params, carry, obs [N, obs], prev_reward [N], t, rng) -> (carry, action [N, act])
Policy = Callable[[Any, Any, jax.Array, jax.Array, jax.Array, jax.Array], tuple[Any, jax.Array]]


def random_policy(params, carry, obs, prev_reward, t, rng):
    """Uniform random actions in ``[-1, 1]``; ``params`` is the action dimension's template ``[act]``."""
    return carry, jax.random.uniform(rng, (obs.shape[0],) + params.shape, minval=-1.0, maxval=1.0)
