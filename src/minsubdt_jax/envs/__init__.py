"""Environments: hopper, walker, halfcheetah; their rules in two dynamics (brax, d4rl) written once
(:mod:`~minsubdt_jax.envs.rules`), two physics backends (MJX, C MuJoCo) that run them, batched rollouts of any
policy, and the check of which dynamics a dataset came from."""

from .check import check_dynamics, dynamics_report
from .mjx_backend import EnvState, MjxEnv
from .rollout import PHYSICS, make_rollout, make_seed_rollout, physics_record, resolve_physics
from .rules import DYNAMICS, env_rules, mj_model
from .spec import ENVS, EnvSpec, Policy, Rollout, check_dataset, env_spec, random_policy

__all__ = ["DYNAMICS", "ENVS", "EnvSpec", "EnvState", "MjxEnv", "PHYSICS", "Policy", "Rollout", "check_dataset",
           "check_dynamics", "dynamics_report", "env_rules", "env_spec", "make_rollout", "make_seed_rollout",
           "mj_model", "physics_record", "random_policy", "resolve_physics"]
