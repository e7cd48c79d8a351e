"""A training run's setup (:func:`minsubdt_jax.train.train`'s first stages): every check before anything is
written (:func:`plan_run`), each model's data (:func:`prepare_models`), and the run's first writes, its agent and
the models' states (:func:`start_run`)."""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass

import jax
import numpy as np
import orbax.checkpoint as ocp

from .agents import AGENTS, batch_size_of, make_agent
from .agents.base import init_seed_states, optimizer_for
from .config import Config, validate
from .costs import cost_metrics
from .data.d4rl import file_dynamics
from .envs import resolve_physics
from .methods import get_method
from .parallel import assert_same_across_processes, init_distributed, is_main_process, make_mesh
from .pipeline import load, prepare
from .program import check_memory, program_models, stack_models
from .rundir import (DATASET_FILE, COST_METRICS_FILE, RunLock, check_run_dir, check_same_data, check_same_metrics,
                     checkpoint_manager, json_text, write_atomic)

# Fields that may differ between a run and its resumption.
RESUMABLE_CHANGES = ("steps", "eval_episodes", "eval_every", "eval_episodes_periodic", "out", "preset", "devices",
                     "logger", "coordinator_address", "num_processes", "process_id", "physics", "physics_threads")



@dataclass(frozen=True)
class RunPlan:
    """What every stage of a run reads: the checked config, its methods and models, where it writes, who writes,
    the device mesh and physics, the datasets (loaded) and the dynamics they are evaluated in."""

    cfg: Config
    methods: list
    models: list
    out: str
    resume: bool
    main: bool
    verbose: bool
    mesh: object
    physics: str
    batch_size: int
    metric_records: list  # the cost metrics' records (CostMetric.record), what cost_metrics.json holds
    sources: list
    dynamics: str
    dynamics_how: dict


def check_agent_settings(cfg: Config, name: str):
    """The agent ``name``'s record (:class:`~minsubdt_jax.agents.AgentInfo`), after the checks it asks for: one
    dataset per program where its step reads every stored episode, ``--precision`` only where it reads it."""
    agent = AGENTS[name]
    if len(cfg.datasets) > 1 and agent.one_dataset:
        raise ValueError(f"the {name} agent's step reads every stored episode, so its datasets cannot share one "
                         f"program: train them apart")
    if cfg.precision != "f32" and "precision" not in agent.fields:
        raise ValueError(f"--precision {cfg.precision} is for the DT and the critic agents; --method {cfg.method} "
                         f"trains the {name} agent, which has one")
    return agent


def plan_run(cfg: Config, resume: bool, verbose: bool, metrics) -> RunPlan:
    """Every check that can fail on the config, the run directory, the devices, the metrics and the data, before
    anything is written; the datasets are loaded (or recorded on first use) here."""
    cfg = validate(cfg)
    methods = [get_method(m) for m in cfg.methods]
    init_distributed(cfg.coordinator_address, cfg.num_processes, cfg.process_id)
    main = is_main_process()
    out = cfg.run_dir()
    agent = check_agent_settings(cfg, methods[0].agent)
    decays = cfg.lr_schedule != "constant" or agent.fixed_steps
    if resume and decays and os.path.exists(os.path.join(out, "config.json")):
        with open(os.path.join(out, "config.json")) as f:  # the decay ends at --steps: it may not change
            if json.load(f)["steps"] != cfg.steps:
                what = (f"--lr-schedule {cfg.lr_schedule} decays to 0 at" if cfg.lr_schedule != "constant"
                        else f"the {methods[0].agent} agent's schedule is fixed by")
                raise ValueError(f"--resume: {what} the run's --steps: resume with the same --steps")
    check_run_dir(dataclasses.asdict(cfg), out, _ckpt_dir(out), resume, RESUMABLE_CHANGES,
                  dataclasses.asdict(Config()))
    batch_size = batch_size_of(methods[0].agent, cfg)
    mesh = make_mesh(cfg.devices, batch_size)  # checked before anything is written
    check_memory(cfg, agent, len(cfg.datasets) * len(methods) * cfg.seeds, mesh.size)
    physics = resolve_physics(cfg.physics, mesh)
    if metrics is not None and cfg.costs is not None:
        raise ValueError("give the cost metrics once: as cfg.costs (names) or as train(..., metrics=...)")
    metric_records = [m.record() for m in cost_metrics(cfg.env, cfg.costs if metrics is None else metrics)]  # checked
    check_same_metrics(out, metric_records, resume)  # before anything is written
    verbose = verbose and main
    sources = [load(dataclasses.replace(cfg, dataset=d), verbose, physics) for d in cfg.datasets]
    found = [file_dynamics(src, cfg.env, cfg.dynamics) for src in sources]
    if len({d for d, _ in found}) > 1:
        raise ValueError(f"--dataset {cfg.dataset}: the datasets have different dynamics "
                         f"({', '.join(f'{n}: {d}' for n, (d, _) in zip(cfg.datasets, found))}); one program "
                         f"evaluates in one: train them apart")
    dynamics, dynamics_how = found[0]
    if verbose:
        print(f"evaluation in {dynamics} dynamics ({dynamics_how['how']}), {physics} physics", flush=True)
    models = program_models(methods, list(range(cfg.seed, cfg.seed + cfg.seeds)), cfg.datasets)
    return RunPlan(cfg, methods, models, out, resume, main, verbose, mesh, physics, batch_size, metric_records, sources,
                   dynamics, dynamics_how)


def _ckpt_dir(out: str) -> str:
    return os.path.abspath(os.path.join(out, "checkpoints"))


@dataclass(frozen=True)
class ModelData:
    """Each model's prepared data (``preps``: one :class:`~minsubdt_jax.pipeline.Prepared` per dataset and method,
    and per seed where the features are learned; ``per_model``: the one of each model) and the program's stacked
    sampler arrays (``data``, the models' axis ``data_axis``)."""

    preps: dict
    per_model: list
    data: object
    data_axis: int | None


@dataclass(frozen=True)
class Started:
    """What :func:`start_run` made: the agent, its optimiser ``tx``, the models' stacked ``state`` (restored on
    resume), the checkpoint manager and the ``start`` step."""

    agent: object
    tx: object
    state: object
    mngr: object
    start: int


@dataclass(frozen=True)
class Trained:
    """What the training loop ends with: the models' ``state``, the ``step`` reached and the ``seconds`` it took."""

    state: object
    step: int
    seconds: float


def prepare_models(run: RunPlan, metrics) -> ModelData:
    """Each model's prepared data (one per dataset and method, and per seed where the features are learned: they
    depend on the seed) and the program's stacked sampler arrays; the data is checked to be the same in every
    process and, on resume, the run's."""
    preps, per_model = prepare_each(run.cfg, run.models, run.sources, run.dynamics, metrics, run.verbose)
    data, data_axis = stack_models(per_model)
    assert_same_across_processes([np.asarray(x) for x in jax.tree.leaves(data)],
                                 "the training data (every process must load the same dataset)")
    check_same_data(run.out, _sha256(run), run.resume)
    return ModelData(preps, per_model, data, data_axis)


def restore_latest(out: str, state, restore: bool = True):
    """``(state, mngr)``: the run's checkpoint manager and, with ``restore``, ``state`` (the template of the models'
    stacked states) restored from its last checkpoint where it has one (training's resume, and a run read back by
    :mod:`minsubdt_jax.evaluate`)."""
    mngr = checkpoint_manager(_ckpt_dir(out), keep=2)
    if restore and mngr.latest_step() is not None:
        state = mngr.restore(mngr.latest_step(), args=ocp.args.StandardRestore(state))
    return state, mngr


def prepare_each(cfg: Config, models: list, sources: list, dynamics: str, metrics, verbose: bool):
    """``(preps, per_model)``: the prepared data of each model of ``models`` on ``sources`` (one per entry of
    ``cfg.datasets``), one :class:`~minsubdt_jax.pipeline.Prepared` per dataset and method, and per seed where the
    features are learned (they depend on the seed), shared by the models that have the same."""
    names = cfg.datasets
    preps, per_model = {}, []
    for mo in models:
        d = mo.dataset or names[0]
        key = (d, mo.method.name, mo.seed if mo.method.features == "learned" else None)
        if key not in preps:
            preps[key] = prepare(dataclasses.replace(cfg, seed=mo.seed, dataset=d), mo.method, verbose,
                                 sources[names.index(d)], dynamics, metrics)
        per_model.append(preps[key])
    return preps, per_model


def program_agent(cfg: Config, methods: list, sources: list, n_metrics: int):
    """The agent of a program of ``methods`` on ``sources``, sized for their data and longest episode; a DT with a
    return token per metric (``n_metrics`` of them) for a vector method."""
    data = sources[0].data  # a preference-conditioned method's states carry the preference, one weight per metric
    return make_agent(methods[0].agent, cfg, data.obs_dim + (n_metrics if methods[0].preference else 0), data.act_dim,
                      max([cfg.episode_length] + [src.data.max_len for src in sources]),
                      return_dim=n_metrics if methods[0].vector else 0)


def _sha256(run: RunPlan) -> str:
    return "+".join(src.sha256 for src in run.sources)


def start_run(run: RunPlan, lock: RunLock) -> Started:
    """The run's first writes (lock, ``config.json``, ``cost_metrics.json``, ``dataset.json``), the agent, its
    optimiser and the models' states, restored from the last checkpoint on resume."""
    cfg, out = run.cfg, run.out
    if run.main:
        lock.acquire(out)  # a second process into the same --out stops here, having written nothing
        write_atomic(os.path.join(out, "config.json"), cfg.to_json())
        write_atomic(os.path.join(out, COST_METRICS_FILE), json_text(run.metric_records, indent=2))
        record = lambda src: {"path": src.path, "sha256": src.sha256, "episodes": src.data.num_trajectories,  # noqa
                              "transitions": src.data.num_transitions, "dynamics": run.dynamics,
                              "recorded_physics": src.physics}
        write_atomic(os.path.join(out, DATASET_FILE), json.dumps(
            record(run.sources[0]) if len(run.sources) == 1 else
            {"sha256": _sha256(run), "dynamics": run.dynamics, "datasets": [record(src) for src in run.sources]},
            indent=2))
    agent = program_agent(cfg, run.methods, run.sources, len(run.metric_records))
    tx = optimizer_for(agent, cfg)
    state = init_seed_states(agent, tx, [mo.seed for mo in run.models], ema=cfg.ema_decay > 0)
    state, mngr = restore_latest(out, state, run.resume)
    start = int(np.asarray(state.step)[0])
    if run.verbose and run.resume:
        print(f"resumed from step {start}", flush=True)
    if run.verbose and (run.mesh.size > 1 or len(run.models) > 1):
        print(f"{len(run.models)} model(s) ({len(cfg.datasets)} dataset(s) x {len(run.methods)} method(s) x "
              f"{cfg.seeds} seed(s)) in one program; batch split over {run.mesh.size} device(s) in "
              f"{jax.process_count()} process(es): {run.batch_size // run.mesh.size} "
              f"{'transitions' if AGENTS[run.methods[0].agent].transitions else 'sequences'} each", flush=True)
    return Started(agent, tx, state, mngr, start)
