"""Which physics runs a rollout: ``mjx`` (MJX, jitted, on any JAX device) or ``mujoco`` (C MuJoCo on the CPU's
cores, :mod:`minsubdt_jax.envs.c_backend`), and the rollout of S models in one program on either.

``auto`` is C MuJoCo when JAX runs on the CPU in one process on one device, else MJX: on this 2-core CPU C MuJoCo
steps hopper 6x, walker 25x and halfcheetah 37x faster than MJX (``benchmarks/README.md``). The rules, the resets and
the policy's keys are the same on both, so a choice of physics changes no semantics, only float rounding.
"""

from __future__ import annotations

import functools

import jax

from .c_backend import default_threads, make_c_rollout, make_c_seed_rollout
from .mjx_backend import make_mjx_rollout
from .rules import check_dynamics_name
from .spec import Policy

PHYSICS = ("auto", "mjx", "mujoco")


def resolve_physics(physics: str = "auto", mesh=None) -> str:
    """``mjx`` or ``mujoco`` for the choice ``physics`` on ``mesh`` (a device mesh, or ``None`` for one device).

    Raises:
      ValueError: an unknown name, or ``mujoco`` with a mesh of several devices or several processes (C MuJoCo
        runs on this process's CPU cores; there, use ``mjx``).
    """
    if physics not in PHYSICS:
        raise ValueError(f"unknown physics {physics!r}; choose one of {list(PHYSICS)}")
    single = (mesh is None or mesh.size == 1) and jax.process_count() == 1
    if physics == "auto":
        return "mujoco" if single and jax.default_backend() == "cpu" else "mjx"
    if physics == "mujoco" and not single:
        size = 1 if mesh is None else mesh.size
        raise ValueError(f"--physics mujoco runs on one process's CPU cores, not on a mesh of {size} device(s) in "
                         f"{jax.process_count()} process(es): use --physics mjx (or auto) with --devices/processes")
    return physics


def physics_record(physics: str, dynamics: str, threads: int = 0) -> dict:
    """What ``results.json`` and dataset files say about the physics that ran."""
    out = {"physics": physics, "dynamics": dynamics}
    if physics == "mujoco":
        out["threads"] = threads or default_threads()
    return out


def make_rollout(env: str, policy: Policy, num_episodes: int, horizon: int, mesh=None, *, physics: str = "auto",
                 dynamics: str = "brax", threads: int = 0):
    """``run(policy_params, policy_carry, rng) -> Rollout`` for ``num_episodes`` parallel episodes of ``policy``
    in ``physics`` (see :func:`resolve_physics`) under ``dynamics`` (:mod:`minsubdt_jax.envs.rules`).

    Actions are clipped to ``[-1, 1]`` (recorded clipped); an ended episode's state is frozen and its later entries
    are zero; termination is kept apart from the time-out at ``horizon``. ``policy_params`` and ``policy_carry``
    are traced: one compile serves every parameter value. ``mesh`` (MJX only) splits the episodes over devices."""
    physics, n, H = _checked(physics, mesh, dynamics, num_episodes, horizon)
    if physics == "mujoco":
        return make_c_rollout(env, policy, n, H, dynamics, threads)
    return _mjx_rollout(env, policy, n, H, mesh, dynamics)


@functools.lru_cache(maxsize=32)
def _mjx_rollout(env, policy, n, H, mesh, dynamics):
    return make_mjx_rollout(env, policy, n, H, mesh, dynamics)


@functools.lru_cache(maxsize=16)
def make_seed_rollout(env: str, policy: Policy, num_episodes: int, horizon: int, mesh=None, *,
                      physics: str = "auto", dynamics: str = "brax", threads: int = 0):
    """``run(inputs [S, ...], carry, rngs [S]) -> Rollout [S, n, ...]``: S models of ``policy`` (its traced inputs
    with a leading seed axis, the initial carry shared) in one program: ``jit(vmap)`` of the MJX rollout, or one C
    batch of ``S x n`` simulations with the policy ``vmap``-ped over the seed axis."""
    physics, n, H = _checked(physics, mesh, dynamics, num_episodes, horizon)
    if physics == "mujoco":
        return make_c_seed_rollout(env, policy, n, H, dynamics, threads)
    return jax.jit(jax.vmap(_mjx_rollout(env, policy, n, H, mesh, dynamics), in_axes=(0, None, 0)))


def _checked(physics, mesh, dynamics, num_episodes, horizon):
    check_dynamics_name(dynamics)
    n, H = int(num_episodes), int(horizon)
    if n < 1 or H < 1:
        raise ValueError(f"num_episodes and horizon must be >= 1, got {n} and {H}")
    if mesh is not None and n % mesh.size:
        raise ValueError(f"num_episodes ({n}) must be divisible by the mesh size ({mesh.size})")
    return resolve_physics(physics, mesh), n, H
