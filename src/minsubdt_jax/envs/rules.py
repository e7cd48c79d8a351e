"""Each env's rules, written once for every physics backend: the model, the reset distribution, the observation,
the reward and the termination, as functions of the physics state.

Two sets of rules (``dynamics``):

* ``brax``: brax 0.14.2's ``hopper``, ``walker2d`` and ``halfcheetah`` (``brax/envs/*.py`` on brax's XMLs: Euler,
  4 solver iterations, only some geoms touching the floor). obs[0] of hopper and walker and the forward progress
  of all three are read from the torso's ``xpos``, which after a step is one substep behind ``qpos``. Our own
  recordings are in these dynamics.
* ``d4rl``: gym's v2/v3 rules, which gymnasium keeps as ``Hopper-v4``, ``Walker2d-v4`` and ``HalfCheetah-v4``, on
  gym's XMLs as gymnasium ships them (RK4 for hopper and walker, 100 solver iterations, every geom colliding;
  walker foot friction 0.9 / 1.9). D4RL recorded its datasets with these classes (mujoco-py, gym < 0.24).
  Everything is read from ``qpos``/``qvel``; the healthy reward is paid on the terminal step too (v5 does not).

The functions take an array namespace ``xp`` (``jax.numpy`` for MJX, ``numpy`` for C MuJoCo in float64), so the
two backends run the same rules. ``torso`` is the torso body's ``xpos`` ``[..., 3]``.
"""

from __future__ import annotations

import functools
import importlib.util
import os
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .spec import env_spec

DYNAMICS = ("brax", "d4rl")
TORSO = 1  # body id of the torso in every model here (body 0 is the world)
# gymnasium's asset names for the d4rl dynamics (gym's v2-v4 XMLs; walker2d.xml is v4's, not walker2d_v5.xml)
_GYM_XML = {"hopper": "hopper.xml", "walker": "walker2d.xml", "halfcheetah": "half_cheetah.xml"}
_BRAX_XML = {"hopper": "hopper.xml", "walker": "walker2d.xml", "halfcheetah": "half_cheetah.xml"}


@dataclass(frozen=True)
class Rules:
    """One env's rules in one dynamics (:func:`env_rules`). Ranges are open intervals, as in brax and gym."""

    env: str
    dynamics: str
    frame_skip: int
    dt: float  # timestep x frame_skip
    ctrl_cost: float
    reset_noise: float  # qpos0 + U(±noise); qvel U(±noise), or noise x N(0, 1) when qvel_noise_normal
    qvel_noise_normal: bool
    clip_qvel: bool  # observe clip(qvel, ±10)
    height_from_torso: bool  # obs[0] is the torso's xpos z (brax hopper/walker), else qpos[1]
    forward_from_torso: bool  # forward progress is the torso's xpos x (brax), else qpos[0]
    healthy_reward: float
    z_range: tuple[float, float] | None
    angle_range: tuple[float, float] | None
    state_range: tuple[float, float] | None  # bounds on qpos[2:] and qvel (hopper)

    @property
    def terminates(self) -> bool:
        return self.z_range is not None


def check_dynamics_name(dynamics: str) -> str:
    if dynamics not in DYNAMICS:
        raise ValueError(f"unknown dynamics {dynamics!r}; choose one of {list(DYNAMICS)}")
    return dynamics


@functools.lru_cache(maxsize=None)
def env_rules(env: str, dynamics: str = "brax") -> Rules:
    """The :class:`Rules` of ``env`` in ``dynamics`` (``brax`` or ``d4rl``)."""
    name = env_spec(env).name
    check_dynamics_name(dynamics)
    brax = dynamics == "brax"
    model = mj_model(name, dynamics)
    skip = 5 if name == "halfcheetah" else 4
    common = dict(env=name, dynamics=dynamics, frame_skip=skip, dt=float(model.opt.timestep) * skip,
                  forward_from_torso=brax)
    if name == "halfcheetah":
        return Rules(**common, ctrl_cost=0.1, reset_noise=0.1, qvel_noise_normal=True, clip_qvel=False,
                     height_from_torso=False, healthy_reward=0.0, z_range=None, angle_range=None, state_range=None)
    hopper = name == "hopper"
    return Rules(**common, ctrl_cost=1e-3, reset_noise=5e-3, qvel_noise_normal=False, clip_qvel=True,
                 height_from_torso=brax, healthy_reward=1.0, z_range=(0.7, float("inf")) if hopper else (0.8, 2.0),
                 angle_range=(-0.2, 0.2) if hopper else (-1.0, 1.0), state_range=(-100.0, 100.0) if hopper else None)


def import_mjx():
    """``mujoco.mjx``, imported without the two lines its optional MuJoCo Warp backend prints when ``warp`` is not
    installed ("Failed to import warp", "Failed to import mujoco_warp": we never use that backend); anything else
    it prints passes through."""
    import contextlib
    import io
    import sys

    if "mujoco.mjx" not in sys.modules:
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            importlib.import_module("mujoco.mjx")
        rest = [line for line in buf.getvalue().splitlines() if not line.startswith(("Failed to import warp",
                                                                                       "Failed to import mujoco_warp"))]
        if rest:
            print("\n".join(rest))
    return sys.modules["mujoco.mjx"]


@functools.lru_cache(maxsize=None)
def mj_model(env: str, dynamics: str = "brax"):
    """The ``mujoco.MjModel`` of ``env`` in ``dynamics``: brax's XML as brax loads it (``mjcf.load_mjmodel``, the
    model its MJX envs run), or gym's XML from gymnasium's package assets. Shared: do not modify it."""
    import mujoco

    name = env_spec(env).name
    if check_dynamics_name(dynamics) == "brax":
        import_mjx()  # brax imports it
        from brax.io import mjcf

        spec = importlib.util.find_spec("brax")
        return mjcf.load_mjmodel(os.path.join(spec.submodule_search_locations[0], "envs", "assets", _BRAX_XML[name]))
    spec = importlib.util.find_spec("gymnasium")
    if spec is None:
        raise ValueError("the d4rl dynamics load gym's XMLs from the gymnasium package: pip install gymnasium")
    return mujoco.MjModel.from_xml_path(
        os.path.join(spec.submodule_search_locations[0], "envs", "mujoco", "assets", _GYM_XML[name]))


def reset_state(rules: Rules, qpos0, key):
    """``(qpos [nq], qvel [nv])`` of a fresh episode from ``key``: brax's own draw (``envs/*.py``: ``reset``), the
    same distribution as gym's ``reset_model``. Every backend draws its resets here (in JAX, float32)."""
    _, k1, k2 = jax.random.split(key, 3)
    noise = rules.reset_noise
    qpos = jnp.asarray(qpos0, jnp.float32) + jax.random.uniform(k1, np.shape(qpos0), minval=-noise, maxval=noise)
    nv = np.shape(qpos0)[0]  # nq == nv for these planar models
    if rules.qvel_noise_normal:
        qvel = noise * jax.random.normal(k2, (nv,))
    else:
        qvel = jax.random.uniform(k2, (nv,), minval=-noise, maxval=noise)
    return qpos, qvel


def observe(rules: Rules, qpos, qvel, torso, xp=jnp):
    """The observation ``[..., obs]`` of states ``qpos [..., nq]``, ``qvel [..., nv]``, ``torso [..., 3]``."""
    height = torso[..., 2:3] if rules.height_from_torso else qpos[..., 1:2]
    vel = xp.clip(qvel, -10.0, 10.0) if rules.clip_qvel else qvel
    return xp.concatenate([height, qpos[..., 2:], vel], axis=-1)


def forward_position(rules: Rules, qpos, torso):
    """The x that the forward reward differentiates ``[...]``."""
    return torso[..., 0] if rules.forward_from_torso else qpos[..., 0]


def is_healthy(rules: Rules, qpos, qvel, torso, xp=jnp):
    """``[...]`` bool: the state is within the env's healthy ranges (always, for halfcheetah)."""
    ok = xp.ones(qpos.shape[:-1], bool)
    if rules.z_range is not None:
        z = torso[..., 2] if rules.height_from_torso else qpos[..., 1]  # brax tests the torso's xpos, gym qpos[1]
        ok = ok & (rules.z_range[0] < z) & (z < rules.z_range[1])
    if rules.angle_range is not None:
        ok = ok & (rules.angle_range[0] < qpos[..., 2]) & (qpos[..., 2] < rules.angle_range[1])
    if rules.state_range is not None:
        s = xp.concatenate([qpos[..., 2:], qvel], axis=-1)
        ok = ok & xp.all((rules.state_range[0] < s) & (s < rules.state_range[1]), axis=-1)
    return ok


def step_outcome(rules: Rules, x_before, qpos, qvel, torso, action, xp=jnp):
    """``(reward [...], done [...])`` of one decision step: forward velocity + healthy reward − control cost, and
    termination (not healthy; never for halfcheetah). ``x_before`` is :func:`forward_position` before the step,
    ``qpos``/``qvel``/``torso`` the state after it, ``action [..., act]`` the (clipped) action."""
    velocity = (forward_position(rules, qpos, torso) - x_before) / rules.dt
    reward = velocity + rules.healthy_reward - rules.ctrl_cost * xp.sum(xp.square(action), axis=-1)
    done = ~is_healthy(rules, qpos, qvel, torso, xp) if rules.terminates else xp.zeros(reward.shape, bool)
    return reward, done
