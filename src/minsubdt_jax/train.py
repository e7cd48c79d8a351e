"""Train one method of the table on one dataset, evaluating it in MJX along the way and at the end.

    python -m minsubdt_jax.train --env walker                            # MinSubDT, engineered costs, cpu preset
    python -m minsubdt_jax.train --env walker --method minsubdt-learned  # costs learned from preferences (eq. 3)
    python -m minsubdt_jax.train --env hopper --method dt                # Decision Transformer on the true rewards
    python -m minsubdt_jax.train --env hopper --method bc-mlp            # BC with an MLP (bc: the DT's architecture)
    python -m minsubdt_jax.train --env hopper --preset smoke --eval-every 10 --out /tmp/run
    python -m minsubdt_jax.train --env hopper --out /tmp/run --resume    # continue after an interruption
    python -m minsubdt_jax.train --env hopper --seeds 3                  # seeds 0, 1, 2 as one vmapped program

Several processes (one machine or many; each runs the same command with its own --process-id):

    python -m minsubdt_jax.train --env hopper --num-processes 2 --process-id 0 --coordinator-address localhost:8476 &
    python -m minsubdt_jax.train --env hopper --num-processes 2 --process-id 1 --coordinator-address localhost:8476

The data side is :mod:`minsubdt_jax.pipeline`, the method a record of :mod:`minsubdt_jax.methods`, the learner an
agent of :mod:`minsubdt_jax.agents`, the scoring :mod:`minsubdt_jax.evaluation`. Here: the run. ``--seeds S`` models
train in one jitted ``lax.scan`` chunk (``vmap`` over a leading seed axis), the batch split over every device of
every process (:mod:`minsubdt_jax.parallel`); an orbax checkpoint follows each chunk; every ``--eval-every`` steps
and at the end all seeds are evaluated in one rollout program. The run directory holds ``config.json``,
``dataset.json``, ``metrics.jsonl`` (loss per chunk, evaluations), ``results.json``, ``learning_curve.png`` and
``checkpoints/``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from typing import Callable

import jax
import numpy as np
import orbax.checkpoint as ocp

from .agents import FIXED_STEPS, batch_size_of, make_agent
from .agents.base import (eval_params, init_seed_states, make_train_chunk, merge_losses, optimizer_for,
                          piece_steps)
from .agents.dt.networks import DT_REVISION
from .caches import enable_compilation_cache
from .config import Config, parse_args, validate
from .costs import cost_metrics
from .data.d4rl import file_dynamics
from .envs import physics_record, resolve_physics
from .evaluation import across_seeds
from .loggers import Loggers, logger_names
from .methods import get_method
from .parallel import (assert_same_across_processes, gather, init_distributed, is_main_process, make_mesh,
                       replicate)
from .pipeline import load, prepare
from .program import check_memory, eval_record, evaluate_models, stack_models
from .references import REFERENCE_SOURCES, references_record
from .rundir import (DATASET_FILE, METRICS_FILE, InterruptFlag, Interrupted, RunLock, check_run_dir, check_same_data,
                     check_same_metrics, exit_code, json_text, plot_learning_curve, progress, truncate_metrics,
                     write_atomic)

# Fields that may differ between a run and its resumption.
RESUMABLE_CHANGES = ("steps", "eval_episodes", "eval_every", "eval_episodes_periodic", "out", "preset", "devices",
                     "logger", "coordinator_address", "num_processes", "process_id", "physics", "physics_threads")


def train(cfg: Config, resume: bool = False, verbose: bool = True,
          progress_fn: Callable[[int, dict], None] | None = None, metrics=None) -> dict:
    """Run one training job end to end in ``cfg.run_dir()`` (:func:`_train`), its run directory locked against a
    second writer from its first write to its end."""
    lock = RunLock()
    try:
        return _train(cfg, resume, verbose, progress_fn, metrics, lock)
    finally:
        lock.release()


def _train(cfg: Config, resume: bool, verbose: bool, progress_fn, metrics, lock: RunLock) -> dict:
    """Run one training job end to end in ``cfg.run_dir()``; returns the contents of ``results.json``.

    One model per method of ``cfg.methods`` and seed (``cfg.seed ...``, ``cfg.seeds`` of them), method-major, trains
    in one program: they share the dataset and the agent, and differ in their return tokens and seeds. In a
    multi-process job (``cfg.num_processes``) every process calls this, and only process 0 writes the run directory
    (checkpoints are written jointly by orbax). ``progress_fn(step, record)`` (as brax's) receives every record
    written to ``metrics.jsonl``: the loss after each chunk and each evaluation's scores (lists over the models).
    ``metrics`` (names or :class:`~minsubdt_jax.costs.CostMetric`, a user's own) replace ``cfg.costs`` as the cost
    metrics; ``results.json`` names them (``dataset.cost_metrics``). A resumed run needs the same ones again."""
    cfg = validate(cfg)
    methods = [get_method(m) for m in cfg.methods]
    init_distributed(cfg.coordinator_address, cfg.num_processes, cfg.process_id)
    main = is_main_process()
    verbose = verbose and main
    out = cfg.run_dir()
    ckpt_dir = os.path.abspath(os.path.join(out, "checkpoints"))
    decays = cfg.lr_schedule != "constant" or methods[0].agent in FIXED_STEPS
    if resume and decays and os.path.exists(os.path.join(out, "config.json")):
        with open(os.path.join(out, "config.json")) as f:  # the decay ends at --steps: it may not change
            if json.load(f)["steps"] != cfg.steps:
                what = (f"--lr-schedule {cfg.lr_schedule} decays to 0 at" if cfg.lr_schedule != "constant"
                        else f"the {methods[0].agent} agent's schedule is fixed by")
                raise ValueError(f"--resume: {what} the run's --steps: resume with the same --steps")
    check_run_dir(dataclasses.asdict(cfg), out, ckpt_dir, resume, RESUMABLE_CHANGES, dataclasses.asdict(Config()))
    batch_size = batch_size_of(methods[0].agent, cfg)
    mesh = make_mesh(cfg.devices, batch_size)  # checked before anything is written
    check_memory(cfg, methods[0].agent, len(cfg.datasets) * len(methods) * cfg.seeds, mesh.size)
    physics = resolve_physics(cfg.physics, mesh)
    seeds = list(range(cfg.seed, cfg.seed + cfg.seeds))
    models = [(m, s) for m in methods for s in seeds]
    # before anything is written: bad data changes nothing. Only learned costs depend on the seed.
    if metrics is not None and cfg.costs is not None:
        raise ValueError("give the cost metrics once: as cfg.costs (names) or as train(..., metrics=...)")
    chosen = [m.record() for m in cost_metrics(cfg.env, cfg.costs if metrics is None else metrics)]  # checked
    check_same_metrics(out, chosen, resume)  # before anything is written
    names = cfg.datasets
    sources = [load(dataclasses.replace(cfg, dataset=d), verbose, physics) for d in names]
    found = [file_dynamics(src, cfg.env, cfg.dynamics) for src in sources]
    if len({d for d, _ in found}) > 1:
        raise ValueError(f"--dataset {cfg.dataset}: the datasets have different dynamics "
                         f"({', '.join(f'{n}: {d}' for n, (d, _) in zip(names, found))}); one program evaluates "
                         f"in one: train them apart")
    dynamics, dynamics_how = found[0]
    if verbose:
        print(f"evaluation in {dynamics} dynamics ({dynamics_how['how']}), {physics} physics", flush=True)
    if len(names) > 1:  # several datasets, dataset-major: (dataset, method, seed)
        models = [(d, m, s) for d in names for m, s in models]
    preps, per_model = {}, []  # one per dataset and method, and per seed where the features are learned (they
    for model in models:  # depend on the seed)
        m, s = model[-2:]
        d = model[0] if len(model) == 3 else names[0]
        key = (d, m.name, s if m.features == "learned" else None)
        if key not in preps:
            preps[key] = prepare(dataclasses.replace(cfg, seed=s, dataset=d), m, verbose, sources[names.index(d)],
                                 dynamics, metrics)
        per_model.append(preps[key])
    data, data_axis = stack_models(per_model)
    assert_same_across_processes([np.asarray(x) for x in jax.tree.leaves(data)],
                                 "the training data (every process must load the same dataset)")
    sha256 = "+".join(src.sha256 for src in sources)
    check_same_data(out, sha256, resume)
    if main:
        lock.acquire(out)  # a second process into the same --out stops here, having written nothing
        write_atomic(os.path.join(out, "config.json"), cfg.to_json())
        write_atomic(os.path.join(out, METRICS_FILE), json_text(chosen, indent=2))
        record = lambda src: {"path": src.path, "sha256": src.sha256, "episodes": src.data.num_trajectories,  # noqa
                              "transitions": src.data.num_transitions, "dynamics": dynamics,
                              "recorded_physics": src.physics}
        write_atomic(os.path.join(out, DATASET_FILE), json.dumps(
            record(sources[0]) if len(sources) == 1 else
            {"sha256": sha256, "dynamics": dynamics, "datasets": [record(src) for src in sources]}, indent=2))
    dataset = sources[0].data
    agent = make_agent(methods[0].agent, cfg, dataset.obs_dim, dataset.act_dim,
                       max([cfg.episode_length] + [src.data.max_len for src in sources]),
                       return_dim=len(chosen) if methods[0].vector else 0)
    tx = optimizer_for(agent, cfg)
    state = init_seed_states(agent, tx, [model[-1] for model in models], ema=cfg.ema_decay > 0)
    mngr = ocp.CheckpointManager(ckpt_dir, options=ocp.CheckpointManagerOptions(max_to_keep=2, create=True))
    if resume and mngr.latest_step() is not None:
        state = mngr.restore(mngr.latest_step(), args=ocp.args.StandardRestore(state))
    start = int(np.asarray(state.step)[0])
    if verbose and resume:
        print(f"resumed from step {start}", flush=True)
    state, data = replicate((state, data), mesh)
    if verbose and (mesh.size > 1 or len(models) > 1):
        print(f"{len(models)} model(s) ({len(names)} dataset(s) x {len(methods)} method(s) x {len(seeds)} seed(s)) in "
              f"one program; batch split "
              f"over {mesh.size} device(s) in "
              f"{jax.process_count()} process(es): {batch_size // mesh.size} "
              f"{'transitions' if hasattr(agent, 'make_step') else 'sequences'} each", flush=True)
    metrics_path = os.path.join(out, "metrics.jsonl")
    if main:
        truncate_metrics(metrics_path, start)

    labels = [("" if len(mo) == 2 else f"{mo[0]}-") + f"{mo[-2].name}-s{mo[-1]}" for mo in models]
    loggers = Loggers(logger_names(cfg.logger), out, dataclasses.asdict(cfg), labels) if main else None

    def log(record):
        if main:
            with open(metrics_path, "a") as f:
                f.write(json_text(record) + "\n")
            loggers.log(record)
        if progress_fn is not None:
            progress_fn(record["step"], record)

    def evaluate(params, episodes):
        return evaluate_models(cfg, agent, params, models, per_model, mesh, episodes, physics, dynamics)

    chunks = {}
    t0 = time.time()
    step = start
    bar = progress(total=cfg.steps, initial=start, disable=not verbose)
    stop = InterruptFlag()  # Ctrl-C: this chunk and its checkpoint first, then one line with the resume command
    try:  # an interruption (Ctrl-C, an error, a progress_fn that stops the run) still completes the last checkpoint
        while step < cfg.steps:
            n = min(cfg.chunk_steps, cfg.steps - step)
            m = piece_steps(n, hasattr(agent, "make_chunk"))
            if m not in chunks:
                if verbose and not chunks:
                    bar.write("compiling the train step (the first chunk waits for it) ...")
                chunks[m] = make_train_chunk(agent, tx, batch_size, m, mesh, seed_axis=True, data_axis=data_axis,
                                             ema_decay=cfg.ema_decay)
            tc = time.time()
            pieces = []
            for _ in range(n // m):  # the same steps as one scan of n (the state carries rng and step); the bar moves
                state, piece = chunks[m](state, data)
                pieces.append(jax.block_until_ready(piece))
                bar.update(m)
            losses, parts = merge_losses(pieces)  # [n, S]; a critic agent's losses by name beside
            per_seed = np.asarray(gather(losses)).mean(0)  # [S]
            if not np.isfinite(per_seed).all():
                last = f"the last checkpoint is step {step}" if step else "no checkpoint was written"
                raise ValueError(f"training diverged: non-finite loss {per_seed.tolist()} in steps {step + 1}-"
                                 f"{step + n} (not checkpointed; {last}); try a lower --learning-rate")
            step += n
            # records first, checkpoint last: a resumed run drops the records past its checkpoint and redoes them
            log({"step": step, "loss": float(per_seed.mean()), "loss_per_seed": per_seed.tolist(),
                 **({"loss_parts": {k: float(np.mean(gather(v))) for k, v in parts.items()}} if parts else {}),
                 "chunk_seconds": time.time() - tc})
            if cfg.eval_every and step % cfg.eval_every == 0 and step < cfg.steps:
                rec = eval_record(step, evaluate(eval_params(state), cfg.eval_episodes_periodic))
                if state.ema_params is not None:  # the raw parameters beside their average
                    raw = eval_record(step, evaluate(state.params, cfg.eval_episodes_periodic))
                    rec.update({k.replace("eval_", "eval_raw_", 1): v for k, v in raw.items()
                                if k.startswith("eval_") and k not in ("eval_episodes", "eval_method", "eval_seed")})
                log(rec)
            mngr.save(step, args=ocp.args.StandardSave(state))
            bar.set_postfix(loss=f"{per_seed.mean():.4f}")
            if stop.raised and step < cfg.steps:
                raise Interrupted(f"stopped after the checkpoint at step {step} of {cfg.steps}; resume with: python "
                                  f"-m minsubdt_jax.train --config {os.path.join(out, 'config.json')} --resume")
    finally:
        stop.restore()
        mngr.wait_until_finished()
    bar.close()
    train_seconds = time.time() - t0

    describe = lambda m: {"name": m.name, "label": m.label, "agent": m.agent}  # noqa: E731
    summaries = {id(p): p.summary(cfg.env) for p in preps.values()}  # once per prepared data, not per model
    own = [summaries[id(p)] for p in per_model]
    results = {"config": dataclasses.asdict(cfg), "dataset": own[0],
               "references": references_record(cfg.env, dynamics),
               "physics": {**physics_record(physics, dynamics, cfg.physics_threads), "dynamics_from": dynamics_how},
               "platform": platform(), "seeds": seeds, "dt_revision": DT_REVISION,
               "models": [{**({"dataset": mo[0]} if len(mo) == 3 else {}), "method": mo[-2].name, "seed": mo[-1]}
                          for mo in models],
               "train": {"steps": step, "steps_this_run": step - start, "seconds_this_run": train_seconds}}
    results.update({"method": describe(methods[0])} if len(methods) == 1 else {"methods": [describe(m) for m in methods]})
    if len(preps) > 1:  # the models' own data summaries (min-subdominance on their features, learned costs)
        results["dataset_per_model"] = [{k: v for k, v in d.items() if k != "costs_sample" or len(names) > 1}
                                        for d in own]
    if cfg.eval_episodes:
        te = time.time()
        per = evaluate(eval_params(state), cfg.eval_episodes)
        results["eval_per_seed"] = per  # one entry per model (its method and seed inside)
        name_of = lambda e: e["method"] if len(names) == 1 else f"{e['dataset']}/{e['method']}"  # noqa: E731
        by_method = {}  # method (dataset/method over several datasets) -> its models' indices
        for i, e in enumerate(per):
            by_method.setdefault(name_of(e), []).append(i)
        summary = {k: per[v[0]] if len(v) == 1 else across_seeds([per[i] for i in v]) for k, v in by_method.items()}
        for v in summary.values():
            v["seconds"] = time.time() - te
        if len(summary) == 1:
            results["eval"] = summary[methods[0].name]
        else:
            results["eval_by_method"] = summary
        log(eval_record(step, per, final=True))
        for name, e in summary.items() if verbose else ():
            demo = own[by_method[name][0]]
            over = (f"{cfg.eval_episodes} episodes" if len(seeds) == 1
                    else f"{len(seeds)} seeds x {cfg.eval_episodes} episodes")
            print(f"eval {name}: return {e['return_mean']:.1f} ± {e['return_std']:.1f}, normalised "
                  f"{e['normalized_score_mean']:.1f} ± {e['normalized_score_std']:.1f} over {over} "
                  f"({REFERENCE_SOURCES[dynamics]}), min-subdominance {e['min_subdominance_mean']:.3f} "
                  f"(dataset {demo['min_subdominance_mean']:.3f})")
            demo = demo["costs_mean"]
            print("  costs (lower is better; demos' mean): " + ", ".join(
                f"{k} {v:.3f} ({demo[k]:.3f})" if k in demo else f"{k} {v:.3f}" for k, v in e["costs_mean"].items())
                + f"; dominate the mean demo (no metric worse, one better): {100 * e['better_than_mean_demo_share']:.0f} %")
    if main:
        loggers.close()
        write_atomic(os.path.join(out, "results.json"), json_text(results, indent=2))
        plot_learning_curve(metrics_path, os.path.join(out, "learning_curve.png"),
                            f"{cfg.env} {cfg.dataset}: {cfg.method} ({len(seeds)} seed{'s' * (len(seeds) > 1)})")
    if verbose:
        print(f"wrote {out}/results.json", flush=True)
    return results


def platform() -> dict:
    """What the run ran on (results are compared only within one platform)."""
    dev = jax.devices()[0]
    return {"backend": jax.default_backend(), "device": dev.device_kind, "devices": jax.device_count(),
            "processes": jax.process_count(), "jax": jax.__version__}


def main(argv=None) -> int:
    enable_compilation_cache()
    return exit_code(lambda: train(*parse_args(argv)))


if __name__ == "__main__":
    sys.exit(main())
