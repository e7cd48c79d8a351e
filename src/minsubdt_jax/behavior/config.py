"""Configuration of the SAC behaviour-policy trainer: one dataclass whose every field is a flag of
``python -m minsubdt_jax.behavior.train``."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass

from ..flags import add_flags
from ..envs import ENVS, env_spec


@dataclass(frozen=True)
class SACConfig:
    """Every field is a ``--flag`` of ``python -m minsubdt_jax.behavior.train``."""

    env: str = "hopper"  # hopper | walker | halfcheetah
    steps: int = 300_000  # environment steps (transitions) in total
    seed: int = 0  # seed of the networks, the exploration and the env resets
    out: str | None = None  # default runs/behavior/{env}
    num_envs: int = 8  # parallel MJX envs that collect transitions
    updates_per_transition: int = 1  # gradient updates per collected transition
    batch_size: int = 256  # transitions per gradient update
    hidden: int = 256  # width of the two hidden layers of actor and critics
    learning_rate: float = 3e-4  # Adam, actor, critics and temperature
    gamma: float = 0.99  # discount
    tau: float = 0.005  # Polyak rate of the target critics
    buffer_size: int = 1_000_000  # replay capacity (transitions); fixed for the life of a run
    min_replay: int = 10_000  # uniformly random actions until the buffer holds this many transitions
    episode_length: int = 1000  # time limit of an episode
    chunk_steps: int = 2000  # env steps per jitted chunk (a log line after each)
    eval_every: int = 10_000  # env steps between evaluation + snapshot + checkpoint
    eval_episodes: int = 8  # episodes per evaluation
    # lambda: train on r = v_x - lambda * |a|^2 (+ the healthy reward of hopper and walker) instead of the env's own
    # reward, a policy at one trade-off between speed and energy (behavior.tradeoffs); unset: the env's reward
    energy_weight: float | None = None

    def run_dir(self) -> str:
        return self.out or f"runs/behavior/{env_spec(self.env).name}"

    @property
    def capacity(self) -> int:
        return -(-self.buffer_size // self.num_envs) * self.num_envs


def validate(cfg: SACConfig) -> SACConfig:
    env_spec(cfg.env)
    for name in ("steps", "num_envs", "updates_per_transition", "batch_size", "hidden", "learning_rate",
                 "buffer_size", "episode_length", "chunk_steps", "eval_every", "eval_episodes"):
        if not getattr(cfg, name) > 0:
            raise ValueError(f"--{name.replace('_', '-')} must be > 0, got {getattr(cfg, name)}")
    if cfg.energy_weight is not None and not 0 <= cfg.energy_weight < float("inf"):
        raise ValueError(f"--energy-weight must be finite and >= 0, got {cfg.energy_weight}")
    if not (0 < cfg.gamma < 1 and 0 < cfg.tau <= 1 and cfg.min_replay >= cfg.batch_size):
        raise ValueError("need 0 < --gamma < 1, 0 < --tau <= 1 and --min-replay >= --batch-size")
    for name in ("chunk_steps", "eval_every", "min_replay"):
        if getattr(cfg, name) % cfg.num_envs:
            raise ValueError(f"--{name.replace('_', '-')} must be a multiple of --num-envs ({cfg.num_envs})")
    if cfg.eval_every % cfg.chunk_steps or cfg.min_replay % cfg.chunk_steps:
        raise ValueError("--eval-every and --min-replay must be multiples of --chunk-steps")
    return cfg


def train_command(run_cfg: dict) -> str:
    """The ``behavior.train`` command line of a run's config (``config.json``): its flags off their defaults."""
    defaults = dataclasses.asdict(SACConfig())
    flags = [f"--{k.replace('_', '-')} {v}" for k, v in run_cfg.items() if k != "env" and v != defaults.get(k)]
    return " ".join(["python -m minsubdt_jax.behavior.train --env", run_cfg["env"], *flags])


def parse_args(argv=None) -> tuple[SACConfig, bool]:
    p = argparse.ArgumentParser(prog="python -m minsubdt_jax.behavior.train",
                                description="Train a SAC behaviour policy in MJX (snapshots for datasets).")
    add_flags(p, SACConfig, {"env": tuple(ENVS)})
    p.add_argument("--resume", action="store_true", help="continue from the run directory's last checkpoint")
    args = vars(p.parse_args(argv))
    resume = args.pop("resume")
    return validate(SACConfig(**{k: v for k, v in args.items() if v is not None})), resume
