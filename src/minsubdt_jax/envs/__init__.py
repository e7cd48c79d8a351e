"""Environments: hopper, walker, halfcheetah (and any registered: ``register_env``, one record each); their rules
in two dynamics (brax, d4rl) written once (:mod:`~minsubdt_jax.envs.rules`), two physics backends (MJX, C MuJoCo)
that run them, batched rollouts of any policy, and the check of which dynamics a dataset came from. The env records
(:mod:`~minsubdt_jax.envs.spec`) are imported here; the physics loads on first use of its names, so reading an env's
facts does not load MuJoCo."""

import importlib

from .spec import ENVS, Dynamics, EnvSpec, Policy, Rollout, check_dataset, env_spec, random_policy, register_env

_LAZY = {**dict.fromkeys(("check_dynamics", "dynamics_report"), "check"),
         **dict.fromkeys(("EnvState", "MjxEnv"), "mjx_backend"),
         **dict.fromkeys(("PHYSICS", "make_rollout", "make_seed_rollout", "physics_record", "resolve_physics"),
                         "rollout"),
         **dict.fromkeys(("DYNAMICS", "env_rules", "mj_model"), "rules")}

__all__ = ["DYNAMICS", "Dynamics", "ENVS", "EnvSpec", "EnvState", "MjxEnv", "PHYSICS", "Policy", "Rollout",
           "check_dataset", "check_dynamics", "dynamics_report", "env_rules", "env_spec", "make_rollout", "make_seed_rollout",
           "mj_model", "physics_record", "random_policy", "register_env", "resolve_physics"]


def __getattr__(name):
    """The physics' names, imported from their module on first use (PEP 562)."""
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
