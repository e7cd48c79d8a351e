"""Agents, one folder each (brax's ``training/agents`` layering): ``dt`` (the Decision Transformer that MinSubDT,
DT and DT-architecture BC train), ``mlp`` (behaviour cloning with an MLP), and the critic agents ``iql``, ``td3bc``,
``cql``, ``brac`` (BRAC-v), ``bear`` and ``awr`` on one actor-critic base (:mod:`~minsubdt_jax.agents.actor_critic`,
networks in :mod:`~minsubdt_jax.agents.critic_networks`). Shared pieces are in
:mod:`minsubdt_jax.agents.base`; a new agent is a folder whose ``make_*_agent(cfg, obs_dim, act_dim,
max_timestep)`` returns a record implementing :class:`~minsubdt_jax.agents.base.Agent`, registered below."""

from __future__ import annotations

from .awr.agent import make_awr_agent
from .bear.agent import make_bear_agent
from .brac.agent import make_brac_agent
from .cql.agent import make_cql_agent
from .dt.agent import make_dt_agent
from .iql.agent import make_iql_agent
from .mlp.agent import make_mlp_agent
from .td3bc.agent import make_td3bc_agent

AGENTS = {"dt": make_dt_agent, "mlp": make_mlp_agent, "iql": make_iql_agent, "td3bc": make_td3bc_agent,
          "cql": make_cql_agent, "brac": make_brac_agent, "bear": make_bear_agent,
          "awr": make_awr_agent}
CRITIC_AGENTS = ("iql", "td3bc", "cql", "brac", "bear", "awr")  # train on transitions, --critic-batch-size per step
# a schedule tied to --steps (IQL's actor rate, BRAC-v's pretraining, BEAR's warm-up): a resumed run keeps its --steps
FIXED_STEPS = ("iql", "brac", "bear")


def batch_size_of(name: str, cfg) -> int:
    """Sequences (DT, MLP) or transitions (critic agents) per gradient step of agent ``name``."""
    return cfg.critic_batch_size if name in CRITIC_AGENTS else cfg.batch_size


def make_agent(name: str, cfg, obs_dim: int, act_dim: int, max_timestep: int, return_dim: int = 0):
    """The agent registered as ``name``, sized for the data; ``return_dim`` K > 0: a DT with a return token per cost
    metric (a vector method, :mod:`minsubdt_jax.methods`)."""
    if return_dim:
        return AGENTS[name](cfg, obs_dim, act_dim, max_timestep, return_dim=return_dim)
    return AGENTS[name](cfg, obs_dim, act_dim, max_timestep)
