"""Each env's rules, written once for every physics backend: the model, the reset distribution, the observation,
the reward and the termination, as functions of the physics state.

Three sets of rules (``dynamics``):

* ``brax``: brax 0.14.2's ``hopper``, ``walker2d`` and ``halfcheetah`` (``brax/envs/*.py`` on brax's XMLs: Euler,
  4 solver iterations, only some geoms touching the floor). obs[0] of hopper and walker and the forward progress
  of all three are read from the torso's ``xpos``, which after a step is one substep behind ``qpos``. Our own
  recordings are in these dynamics.
* ``d4rl``: gym's v2/v3 rules, which gymnasium keeps as ``Hopper-v4``, ``Walker2d-v4`` and ``HalfCheetah-v4``, on
  gym's XMLs as gymnasium ships them (RK4 for hopper and walker, 100 solver iterations, every geom colliding;
  walker foot friction 0.9 / 1.9). D4RL recorded its datasets with these classes (mujoco-py, gym < 0.24).
  Everything is read from ``qpos``/``qvel``; the healthy reward is paid on the terminal step too (v5 does not).
* ``v5``: gymnasium's ``Hopper-v5``, ``Walker2d-v5`` and ``HalfCheetah-v5`` at their defaults, in which Minari's
  MuJoCo datasets are recorded: v4's rules but the healthy reward paid only while healthy (not on the terminal step),
  and walker on ``walker2d_v5.xml`` (both feet at friction 1.9). HalfCheetah-v5 is HalfCheetah-v4.

Each env's constants (its XML per dynamics, frame skip, control cost, reset noise, healthy ranges) are its record's
(:class:`~minsubdt_jax.envs.spec.Dynamics` in :data:`~minsubdt_jax.envs.spec.ENVS`); the functions here are the same
for every env. They take an array namespace ``xp`` (``jax.numpy`` for MJX, ``numpy`` for C MuJoCo in float64), so the
two backends run the same rules. ``torso`` is the torso body's ``xpos`` ``[..., 3]``.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import os
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .spec import Dynamics, env_spec

DYNAMICS = ("brax", "d4rl", "v5")
TORSO = 1  # body id of the torso in every model here (body 0 is the world)


@dataclass(frozen=True)
class Rules(Dynamics):
    """One env's rules in one dynamics (:func:`env_rules`): its :class:`~minsubdt_jax.envs.spec.Dynamics` (the
    env record's), with the env, the dynamics' name, the decision step ``dt`` (timestep x frame_skip) and the
    model's ``nv``."""

    env: str = ""
    dynamics: str = ""
    dt: float = 0.0
    nv: int = 0

    @property
    def terminates(self) -> bool:
        return self.z_range is not None


def check_dynamics_name(dynamics: str) -> str:
    if dynamics not in DYNAMICS:
        raise ValueError(f"unknown dynamics {dynamics!r}; choose one of {list(DYNAMICS)}")
    return dynamics


def env_dynamics(env: str, dynamics: str):
    """``(spec, own)``: ``env``'s record and its :class:`~minsubdt_jax.envs.spec.Dynamics` in ``dynamics``; one
    error where the record has none."""
    spec = env_spec(env)
    own = spec.dynamics.get(check_dynamics_name(dynamics))
    if own is None:
        raise ValueError(f"env {spec.name} has no {dynamics} dynamics; it has {sorted(spec.dynamics)}")
    return spec, own


@functools.lru_cache(maxsize=None)
def env_rules(env: str, dynamics: str = "brax") -> Rules:
    """The :class:`Rules` of ``env`` in ``dynamics`` (its record's :class:`~minsubdt_jax.envs.spec.Dynamics`)."""
    spec, own = env_dynamics(env, dynamics)
    model = mj_model(spec.name, dynamics)
    return Rules(**dataclasses.asdict(own), env=spec.name, dynamics=dynamics,
                 dt=float(model.opt.timestep) * own.frame_skip, nv=int(model.nv))


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


def model_file(xml: str) -> str:
    """The path of a :class:`~minsubdt_jax.envs.spec.Dynamics` ``xml``: ``"package:relative/path"`` in the installed
    package, or the path itself."""
    package, sep, rel = xml.partition(":")
    if not sep or os.path.isabs(xml):
        return xml
    spec = importlib.util.find_spec(package)
    if spec is None:
        raise ValueError(f"the model {xml} is a file of the {package} package: pip install {package}")
    return os.path.join(spec.submodule_search_locations[0], rel)


@functools.lru_cache(maxsize=None)
def mj_model(env: str, dynamics: str = "brax"):
    """The ``mujoco.MjModel`` of ``env`` in ``dynamics``: its record's XML (brax's as brax loads it,
    ``mjcf.load_mjmodel``, the model its MJX envs run; gym's from gymnasium's package assets). Shared: do not
    modify it."""
    import mujoco

    _, own = env_dynamics(env, dynamics)
    if own.brax_loader:
        import_mjx()  # brax imports it
        from brax.io import mjcf

        return mjcf.load_mjmodel(model_file(own.xml))
    return mujoco.MjModel.from_xml_path(model_file(own.xml))


def reset_state(rules: Rules, qpos0, key):
    """``(qpos [nq], qvel [nv])`` of a fresh episode from ``key``: brax's own draw (``envs/*.py``: ``reset``), the
    same distribution as gym's ``reset_model``. Every backend draws its resets here (in JAX, float32)."""
    _, k1, k2 = jax.random.split(key, 3)
    noise = rules.reset_noise
    qpos = jnp.asarray(qpos0, jnp.float32) + jax.random.uniform(k1, np.shape(qpos0), minval=-noise, maxval=noise)
    if rules.qvel_noise_normal:
        qvel = noise * jax.random.normal(k2, (rules.nv,))
    else:
        qvel = jax.random.uniform(k2, (rules.nv,), minval=-noise, maxval=noise)
    return qpos, qvel


def observe(rules: Rules, qpos, qvel, torso, xp=jnp):
    """The observation ``[..., obs]`` of states ``qpos [..., nq]``, ``qvel [..., nv]``, ``torso [..., 3]``."""
    k = rules.obs_skip
    pos = xp.concatenate([torso[..., 2:3], qpos[..., k + 1:]], axis=-1) if rules.height_from_torso else qpos[..., k:]
    vel = xp.clip(qvel, -10.0, 10.0) if rules.clip_qvel else qvel
    return xp.concatenate([pos, vel], axis=-1)


def forward_position(rules: Rules, qpos, torso):
    """The x that the forward reward differentiates ``[...]``."""
    return torso[..., 0] if rules.forward_from_torso else qpos[..., 0]


def is_healthy(rules: Rules, qpos, qvel, torso, xp=jnp):
    """``[...]`` bool: the state is within the env's healthy ranges (always, for halfcheetah)."""
    ok = xp.ones(qpos.shape[:-1], bool)
    if rules.z_range is not None:
        z = torso[..., 2] if rules.height_from_torso else qpos[..., rules.z_index]  # brax: the torso's xpos
        ok = ok & (rules.z_range[0] < z) & (z < rules.z_range[1])
    if rules.angle_range is not None:
        angle = qpos[..., rules.angle_index]
        ok = ok & (rules.angle_range[0] < angle) & (angle < rules.angle_range[1])
    if rules.state_range is not None:
        s = xp.concatenate([qpos[..., rules.obs_skip + 1:], qvel], axis=-1)
        ok = ok & xp.all((rules.state_range[0] < s) & (s < rules.state_range[1]), axis=-1)
    return ok


def step_outcome(rules: Rules, x_before, qpos, qvel, torso, action, xp=jnp):
    """``(reward [...], done [...])`` of one decision step: forward velocity + healthy reward − control cost, and
    termination (not healthy; never for halfcheetah). ``x_before`` is :func:`forward_position` before the step,
    ``qpos``/``qvel``/``torso`` the state after it, ``action [..., act]`` the (clipped) action."""
    velocity = (forward_position(rules, qpos, torso) - x_before) / rules.dt
    healthy = is_healthy(rules, qpos, qvel, torso, xp)
    bonus = rules.healthy_reward if rules.healthy_reward_on_fall else rules.healthy_reward * healthy
    reward = velocity + bonus - rules.ctrl_cost * xp.sum(xp.square(action), axis=-1)
    done = ~healthy if rules.terminates else xp.zeros(reward.shape, bool)
    return reward, done
