"""What every physics backend shares: env specs, the data check, the :class:`Rollout` record and the policy
signature."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import jax
import numpy as np
from flax import struct


@dataclass(frozen=True)
class Dynamics:
    """One env's rules in one dynamics (:mod:`~minsubdt_jax.envs.rules` turns them into a ``Rules``): its model
    file and the constants of its reset, observation, reward and termination. Ranges are open intervals.

    ``xml`` is ``"package:relative/path"`` (a file of an installed package) or a path; ``brax_loader`` loads it with
    brax's ``mjcf.load_mjmodel`` (as brax's envs do), else MuJoCo's own. The observation is
    ``[height, qpos[obs_skip + 1:], qvel]`` with the torso's ``xpos`` z as the height (``height_from_torso``), else
    ``[qpos[obs_skip:], qvel]``; ``z_index`` and ``angle_index`` are the qpos entries the healthy ranges test. The
    reset is ``qpos0 + U(±reset_noise)`` and a ``qvel`` of the model's ``nv`` entries, ``U(±reset_noise)`` or
    ``reset_noise x N(0, 1)`` (``qvel_noise_normal``): nothing assumes ``nq == nv``.
    """

    xml: str
    frame_skip: int
    ctrl_cost: float
    reset_noise: float
    qvel_noise_normal: bool = False
    clip_qvel: bool = False  # observe clip(qvel, ±10)
    height_from_torso: bool = False
    forward_from_torso: bool = False  # forward progress is the torso's xpos x (brax), else qpos[0]
    healthy_reward: float = 0.0
    z_range: tuple[float, float] | None = None
    angle_range: tuple[float, float] | None = None
    state_range: tuple[float, float] | None = None  # bounds on qpos[obs_skip + 1:] and qvel (hopper)
    obs_skip: int = 1  # leading qpos entries the observation leaves out (the forward position x)
    z_index: int = 1
    angle_index: int = 2
    brax_loader: bool = False
    healthy_reward_on_fall: bool = True  # the healthy reward is paid on the terminal step too (brax, gym v2-v4)


def planar_dynamics(brax_xml: str, gym_xml: str, v5_xml: str | None = None, torso_height: bool = False,
                    **rules) -> dict:
    """``{"brax": ..., "d4rl": ..., "v5": ...}``: one planar env's rules in brax's env (brax's XML and loader,
    forward progress and, with ``torso_height``, the observed height from the torso's ``xpos``), in gym's v2-v4 env
    (gymnasium's XML, everything from ``qpos``) and in gymnasium's v5 env (its v5 XML, ``v5_xml`` where it has its
    own; the healthy reward only while healthy), with the same constants ``rules`` (:mod:`~minsubdt_jax.envs.rules`)."""
    gym = "gymnasium:envs/mujoco/assets/"
    return {"brax": Dynamics(f"brax:envs/assets/{brax_xml}", brax_loader=True, forward_from_torso=True,
                             height_from_torso=torso_height, **rules),
            "d4rl": Dynamics(gym + gym_xml, **rules),
            "v5": Dynamics(gym + (v5_xml or gym_xml), healthy_reward_on_fall=False, **rules)}


@dataclass(frozen=True)
class EnvSpec:
    """Everything about one environment, in one record (a new env is one record: :func:`register_env`).

    The observation layout the cost metrics read (gym/D4RL layout: ``qpos[obs_skip:]`` then ``qvel``), so they can
    be read from any D4RL-layout dataset as well as from our rollouts: ``x_velocity_index`` (forward speed),
    ``z_velocity_index`` (the torso's vertical speed), ``pitch_index`` (its pitch angle) and ``joint_velocity_start``
    (the leg joints' angular velocities, from there to the end); None where the body has none (a metric that needs
    it is then one error).
    ``reset_obs0`` is ``obs[0]`` in a reset state (torso height for hopper and walker, the root's z offset for
    halfcheetah), in brax MJX and in gym alike: it tells apart datasets of envs with the same shapes.

    The rest is what other layers tune per env: ``terminates`` (episodes end when the body falls), the cost
    metrics' ranges (``speed_hi``: the forward speed of cost 0, m/s; ``joint_speed_hi``, rad/s; ``speed_band`` and
    its saturation ``speed_band_sat``, m/s), D4RL's medium-replay size (``replay_transitions``), its rules and model
    per dynamics (``dynamics``:
    :class:`Dynamics`) and the reference returns of a normalised score per dynamics (``references``: ``(random,
    expert, where they come from)``; D4RL's are d4rl/infos.py's; without an entry for ``brax``, the ones measured with the committed
    behaviour policies, ``behavior/snapshots/{env}/manifest.json``).
    """

    name: str
    obs_dim: int
    act_dim: int
    x_velocity_index: int
    z_velocity_index: int | None
    pitch_index: int | None
    joint_velocity_start: int | None
    reset_obs0: float
    terminates: bool
    speed_hi: float
    joint_speed_hi: float
    speed_band: tuple[float, float]
    speed_band_sat: float
    replay_transitions: int
    dynamics: dict = field(default_factory=dict, hash=False)
    references: dict = field(default_factory=dict, hash=False)


_D4RL_REFS = "D4RL's references (d4rl/infos.py REF_MIN_SCORE / REF_MAX_SCORE)"
_HOPPER_WALKER = dict(frame_skip=4, ctrl_cost=1e-3, reset_noise=5e-3, clip_qvel=True, healthy_reward=1.0)
# reset_obs0 measured as the mean obs[0] of 64 brax MJX resets: 1.25 ± 0.003 (hopper, walker), 0.00 ± 0.06
# (halfcheetah); gym's resets (D4RL) have the same values. Rules: brax 0.14.2's envs/*.py and gym's v3 classes.
ENVS = {
    # hopper's observation: z, pitch, 3 joints, then v_x, v_z, pitch rate, 3 joint speeds
    "hopper": EnvSpec("hopper", 11, 3, x_velocity_index=5, z_velocity_index=6, pitch_index=1, joint_velocity_start=8,
                      reset_obs0=1.25, terminates=True, speed_hi=4.0, joint_speed_hi=10.0,
                      speed_band=(2.0, 3.0), speed_band_sat=2.0, replay_transitions=402_000,
                      dynamics=planar_dynamics("hopper.xml", "hopper.xml", torso_height=True,
                                             z_range=(0.7, float("inf")), angle_range=(-0.2, 0.2),
                                             state_range=(-100.0, 100.0), **_HOPPER_WALKER),
                      references={"d4rl": (-20.272305, 3234.3, _D4RL_REFS)}),
    # walker's and halfcheetah's: z, pitch, 6 joints, then v_x, v_z, pitch rate, 6 joint speeds
    "walker": EnvSpec("walker", 17, 6, x_velocity_index=8, z_velocity_index=9, pitch_index=1, joint_velocity_start=11,
                      reset_obs0=1.25, terminates=True, speed_hi=6.0, joint_speed_hi=10.0,
                      speed_band=(2.5, 3.5), speed_band_sat=2.0, replay_transitions=302_000,
                      dynamics=planar_dynamics("walker2d.xml", "walker2d.xml", "walker2d_v5.xml", torso_height=True,
                                             z_range=(0.8, 2.0), angle_range=(-1.0, 1.0), **_HOPPER_WALKER),
                      references={"d4rl": (1.629008, 4592.3, _D4RL_REFS)}),
    "halfcheetah": EnvSpec("halfcheetah", 17, 6, x_velocity_index=8, z_velocity_index=9, pitch_index=1,
                           joint_velocity_start=11, reset_obs0=0.0, terminates=False, speed_hi=15.0,
                           joint_speed_hi=30.0, speed_band=(4.0, 6.0), speed_band_sat=5.0, replay_transitions=202_000,
                           dynamics=planar_dynamics("half_cheetah.xml", "half_cheetah.xml", frame_skip=5,
                                                    ctrl_cost=0.1, reset_noise=0.1, qvel_noise_normal=True),
                           references={"d4rl": (-280.178953, 12135.0, _D4RL_REFS)}),
}
_ALIASES = {"walker2d": "walker", "half_cheetah": "halfcheetah", "cheetah": "halfcheetah"}
ON_REGISTER: list = []  # called with each env registered later: the gymnasium ids (envs.gym_env), once imported


def register_env(spec: EnvSpec) -> EnvSpec:
    """Add ``spec`` to :data:`ENVS` (a new env from one file: ``tests/test_new_env.py``); an existing name is an
    error. The run, the data and the metrics then take ``env=spec.name`` from the library; the command lines offer
    the envs present when they are imported."""
    if spec.name in ENVS or spec.name in _ALIASES:
        raise ValueError(f"an env named {spec.name!r} exists already")
    if not spec.dynamics:
        raise ValueError(f"env {spec.name!r} names no dynamics (EnvSpec.dynamics: {{name: Dynamics}})")
    ENVS[spec.name] = spec
    for hook in ON_REGISTER:
        hook()
    return spec


def env_spec(name: str) -> EnvSpec:
    """The :class:`EnvSpec` for ``hopper``, ``walker`` (``walker2d``), ``halfcheetah`` or a registered env."""
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
