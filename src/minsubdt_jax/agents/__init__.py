"""Agents, one folder each (brax's ``training/agents`` layering): ``dt`` (the Decision Transformer that MinSubDT,
DT and DT-architecture BC train) and ``mlp`` (behaviour cloning with an MLP). Shared pieces are in
:mod:`minsubdt_jax.agents.base`; a new agent is a folder whose ``make_*_agent(cfg, obs_dim, act_dim,
max_timestep)`` returns a record implementing :class:`~minsubdt_jax.agents.base.Agent`, registered below."""

from __future__ import annotations

from .dt.agent import make_dt_agent
from .mlp.agent import make_mlp_agent

AGENTS = {"dt": make_dt_agent, "mlp": make_mlp_agent}


def make_agent(name: str, cfg, obs_dim: int, act_dim: int, max_timestep: int):
    """The agent registered as ``name``, sized for the data."""
    return AGENTS[name](cfg, obs_dim, act_dim, max_timestep)
