"""Agents, one folder each (brax's ``training/agents`` layering): ``dt`` (the Decision Transformer that MinSubDT,
DT and DT-architecture BC train), ``mlp`` (behaviour cloning with an MLP), and the critic agents ``iql``, ``td3bc``,
``cql``, ``brac`` (BRAC-v), ``bear`` and ``awr`` on one actor-critic base (:mod:`~minsubdt_jax.agents.actor_critic`,
networks in :mod:`~minsubdt_jax.agents.critic_networks`). Shared pieces are in
:mod:`minsubdt_jax.agents.base`; a new agent is a folder whose ``make_*_agent(cfg, obs_dim, act_dim,
max_timestep)`` returns a record implementing :class:`~minsubdt_jax.agents.base.Agent`, registered below."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .awr.agent import make_awr_agent
from .bear.agent import make_bear_agent
from .brac.agent import make_brac_agent
from .cql.agent import make_cql_agent
from .dt.agent import make_dt_agent
from .iql.agent import make_iql_agent
from .mlp.agent import make_mlp_agent
from .td3bc.agent import make_td3bc_agent

@dataclass(frozen=True)
class AgentInfo:
    """What the run and the experiments need to know of an agent, declared once, here.

    Attributes:
      make: ``make(cfg, obs_dim, act_dim, max_timestep) -> agent`` (:class:`~minsubdt_jax.agents.base.Agent`).
      transitions: it trains on transitions, ``--critic-batch-size`` per step (the critic agents), not on windows.
      fixed_steps: a schedule tied to ``--steps`` (IQL's actor rate, BRAC-v's pretraining, BEAR's warm-up): a
        resumed run keeps its ``--steps``.
      one_dataset: its step reads every stored episode (AWR's iteration standardises advantages over them), so
        its datasets cannot share one program.
    """

    make: Callable
    transitions: bool = False
    fixed_steps: bool = False
    one_dataset: bool = False


AGENTS = {"dt": AgentInfo(make_dt_agent), "mlp": AgentInfo(make_mlp_agent),
          "iql": AgentInfo(make_iql_agent, transitions=True, fixed_steps=True),
          "td3bc": AgentInfo(make_td3bc_agent, transitions=True), "cql": AgentInfo(make_cql_agent, transitions=True),
          "brac": AgentInfo(make_brac_agent, transitions=True, fixed_steps=True),
          "bear": AgentInfo(make_bear_agent, transitions=True, fixed_steps=True),
          "awr": AgentInfo(make_awr_agent, transitions=True, one_dataset=True)}
CRITIC_AGENTS = tuple(n for n, a in AGENTS.items() if a.transitions)  # read from the records above
FIXED_STEPS = tuple(n for n, a in AGENTS.items() if a.fixed_steps)


def batch_size_of(name: str, cfg) -> int:
    """Sequences (DT, MLP) or transitions (critic agents) per gradient step of agent ``name``."""
    return cfg.critic_batch_size if AGENTS[name].transitions else cfg.batch_size


def make_agent(name: str, cfg, obs_dim: int, act_dim: int, max_timestep: int, return_dim: int = 0):
    """The agent registered as ``name``, sized for the data; ``return_dim`` K > 0: a DT with a return token per cost
    metric (a vector method, :mod:`minsubdt_jax.methods`)."""
    if return_dim:
        return AGENTS[name].make(cfg, obs_dim, act_dim, max_timestep, return_dim=return_dim)
    return AGENTS[name].make(cfg, obs_dim, act_dim, max_timestep)
