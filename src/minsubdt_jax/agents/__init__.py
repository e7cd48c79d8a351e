"""Agents, one folder each (brax's ``training/agents`` layering): ``dt`` (the Decision Transformer that MinSubDT,
DT and DT-architecture BC train), ``mlp`` (behaviour cloning with an MLP), and the critic agents ``iql``, ``td3bc``,
``cql``, ``brac`` (BRAC-v), ``bear`` and ``awr`` on one actor-critic base (:mod:`~minsubdt_jax.agents.actor_critic`,
networks in :mod:`~minsubdt_jax.agents.critic_networks`). Shared pieces are in
:mod:`minsubdt_jax.agents.base`; a new agent is a folder whose ``make_*_agent(cfg, obs_dim, act_dim,
max_timestep)`` returns a record implementing :class:`~minsubdt_jax.agents.base.Agent`, registered below with
everything the run and the experiments need to know of it (:class:`AgentInfo`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

from ..methods import METHODS
from .awr.agent import make_awr_agent
from .bear.agent import make_bear_agent
from .brac.agent import make_brac_agent
from .cql.agent import make_cql_agent
from .dt.agent import make_dt_agent, train_step_bytes
from .dt.networks import DT_REVISION
from .iql.agent import make_iql_agent
from .mlp.agent import make_mlp_agent
from .td3bc.agent import make_td3bc_agent

# Config fields an agent reads beside its own: the shared step's AdamW (DT, MLP), or a critic agent's optimisers,
# networks, backup and matmul precision (agents/actor_critic.py)
_ADAMW = frozenset({"batch_size", "learning_rate", "weight_decay", "warmup_steps", "grad_clip", "lr_schedule"})
_CRITIC = frozenset({"critic_batch_size", "discount", "tau", "ac_hidden", "ac_layers", "actor_lr", "critic_lr",
                     "precision"})
# a critic agent's own setting at `study`, chosen by its own 3-seed curve (walker medium, EMA), at its reference's
# rates (issue 25; docs/convergence.md). At `study` an agent without an entry has not converged here: table1.py
# refuses it
_STUDY = dict(chunk_steps=2000, lr_schedule="constant", ema_decay=0.999)


@dataclass(frozen=True)
class AgentInfo:
    """What the run and the experiments need to know of an agent, declared once, here.

    Attributes:
      make: ``make(cfg, obs_dim, act_dim, max_timestep) -> agent`` (:class:`~minsubdt_jax.agents.base.Agent`).
      fields: the :class:`~minsubdt_jax.config.Config` fields that only some agents read and this one does (its
        network, optimiser and loss settings; ``tests/test_agents.py`` holds them to what it reads). The
        experiments read them: a result or a curve of this agent differs from another only in the fields it reads
        (:func:`result_fields`).
      presets: its own values over a preset's (``{preset: {field: value}}``, :func:`preset_config`). A preset that
        some agent names is one that every agent of a sweep must name (``{}``: the preset's values are its own).
      transitions: it trains on transitions, ``--critic-batch-size`` per step (the critic agents), not on windows.
      fixed_steps: a schedule tied to ``--steps`` (IQL's actor rate, BRAC-v's pretraining, BEAR's warm-up): a
        resumed run keeps its ``--steps``.
      one_dataset: its step reads every stored episode (AWR's iteration standardises advantages over them), so
        its datasets cannot share one program.
      step_bytes: ``step_bytes(cfg, n_models) -> bytes``, an estimate of one train step's memory, which the run
        checks before it writes anything (the DT's: a long context or a huge batch is one error, not an
        out-of-memory kill); ``None``: not checked.
      revision: the revision of its model's code where a change made it learn differently (the DT's
        ``DT_REVISION``, recorded in every results.json as ``dt_revision``): the experiments never keep or pool
        results of two revisions as one.
      data_settings: its own values per dataset, ``{(env, dataset): {field: value}}`` (``"*"``: any), for the
        fields of its own that a config leaves unset (None): CORL and ReBRAC tune per dataset. The most specific
        match wins (:meth:`settings_for`); :func:`make_agent` fills them in.
    """

    make: Callable
    fields: frozenset = frozenset()
    presets: dict = field(default_factory=dict)
    transitions: bool = False
    fixed_steps: bool = False
    one_dataset: bool = False
    step_bytes: Callable | None = None
    revision: int | None = None
    data_settings: dict = field(default_factory=dict)

    def settings_for(self, env: str, dataset: str) -> dict:
        """Its :attr:`data_settings` for ``env`` and ``dataset``: ``("*", "*")`` first, then the env's, then the
        dataset's, then the pair's, each over the ones before."""
        out = {}
        for key in (("*", "*"), (env, "*"), ("*", dataset), (env, dataset)):
            out.update(self.data_settings.get(key, {}))
        return out


AGENTS = {
    # the DT family's preset values are the DT's own (chosen by its curves, docs/convergence.md)
    "dt": AgentInfo(make_dt_agent, _ADAMW | {"context_len", "embed_dim", "n_layers", "n_heads", "dropout", "precision"},
                    presets={"study": {}}, step_bytes=train_step_bytes, revision=DT_REVISION),
    "mlp": AgentInfo(make_mlp_agent, _ADAMW | {"mlp_hidden", "mlp_layers"}),
    "iql": AgentInfo(make_iql_agent, _CRITIC | {"iql_expectile", "iql_beta"}, {"study": dict(_STUDY, steps=60_000)},
                     transitions=True, fixed_steps=True),
    "td3bc": AgentInfo(make_td3bc_agent, _CRITIC | {"td3bc_alpha"}, {"study": dict(_STUDY, steps=100_000)},
                       transitions=True),
    "cql": AgentInfo(make_cql_agent, _CRITIC | {"cql_alpha", "cql_actions"}, transitions=True),
    "brac": AgentInfo(make_brac_agent, _CRITIC | {"brac_alpha", "pretrain_steps"}, transitions=True,
                      fixed_steps=True),
    # flat by 42k on walker medium on an H200 (docs/convergence.md); a GPU's column (issue 58)
    "bear": AgentInfo(make_bear_agent, _CRITIC | {"pretrain_steps", "bear_kernel"},
                      {"study": dict(_STUDY, steps=60_000)}, transitions=True, fixed_steps=True,
                      # the reference's kernel per env (d4rl_evaluations bear/, d3rlpy's reproduction)
                      data_settings={("*", "*"): {"bear_kernel": "laplacian"},
                                     ("halfcheetah", "*"): {"bear_kernel": "gaussian"}}),
    # 200 iterations of the reference's 1200 steps; its iterations swing, so a longer average
    "awr": AgentInfo(make_awr_agent, _CRITIC - {"tau"},
                     {"study": dict(_STUDY, steps=240_000, chunk_steps=1200, ema_decay=0.9999)},
                     transitions=True, one_dataset=True)}
CRITIC_AGENTS = tuple(n for n, a in AGENTS.items() if a.transitions)  # read from the records above


def agent_of(method: str) -> str:
    """The agent that trains ``method`` (one name, or the first of several comma-separated)."""
    return METHODS[method.split(",")[0].strip()].agent


def preset_config(name: str, method: str = "minsubdt"):
    """The preset ``name`` for ``method`` (one or several, comma-separated, of one agent): the preset's values
    (:data:`~minsubdt_jax.config.PRESETS`), with its agent's own over them (:attr:`AgentInfo.presets`)."""
    from ..config import PRESETS  # here: the config reads the envs, which the agents do not need

    known = method.split(",")[0].strip() in METHODS  # an unknown one is validate's to refuse
    own = AGENTS[agent_of(method)].presets.get(name, {}) if known else {}
    return dataclasses.replace(PRESETS[name], method=method, **own)


def missing_presets(preset: str, methods) -> list[str]:
    """The methods of ``methods`` whose agent has no setting of its own at ``preset`` where some agent has one
    (:attr:`AgentInfo.presets`): trained at the DT family's values they would be no result."""
    if not any(preset in a.presets for a in AGENTS.values()):
        return []
    return [m for m in methods if preset not in AGENTS[agent_of(m)].presets]


def result_fields(agent: str) -> frozenset[str]:
    """The :class:`~minsubdt_jax.config.Config` fields that change what a model of ``agent`` learns or scores:
    all but where and how it ran (:data:`~minsubdt_jax.config.RUN_ONLY_FIELDS`) and the other agents' own fields
    (:attr:`AgentInfo.fields`) that it does not read."""
    from ..config import RUN_ONLY_FIELDS, Config

    others = frozenset().union(*(a.fields for a in AGENTS.values())) - AGENTS[agent].fields
    return frozenset(f.name for f in dataclasses.fields(Config)) - RUN_ONLY_FIELDS - others


def batch_size_of(name: str, cfg) -> int:
    """Sequences (DT, MLP) or transitions (critic agents) per gradient step of agent ``name``."""
    return cfg.critic_batch_size if AGENTS[name].transitions else cfg.batch_size


def make_agent(name: str, cfg, obs_dim: int, act_dim: int, max_timestep: int, return_dim: int = 0):
    """The agent registered as ``name``, sized for the data, with its per-dataset settings for the fields ``cfg``
    leaves unset (:attr:`AgentInfo.data_settings`); ``return_dim`` K > 0: a DT with a return token per cost metric
    (a vector method, :mod:`minsubdt_jax.methods`)."""
    from ..envs import env_spec  # the env's own name (aliases: walker2d)

    own = AGENTS[name].settings_for(env_spec(cfg.env).name, cfg.datasets[0] if len(cfg.datasets) == 1 else "*")
    unset = {k: v for k, v in own.items() if getattr(cfg, k) is None}
    cfg = dataclasses.replace(cfg, **unset) if unset and dataclasses.is_dataclass(cfg) else cfg
    if return_dim:
        return AGENTS[name].make(cfg, obs_dim, act_dim, max_timestep, return_dim=return_dim)
    return AGENTS[name].make(cfg, obs_dim, act_dim, max_timestep)
