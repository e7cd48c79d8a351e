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
agent of :mod:`minsubdt_jax.agents`, the scoring :mod:`minsubdt_jax.scoring`. Here: the run. ``--seeds S`` models
train in one jitted ``lax.scan`` chunk (``vmap`` over a leading seed axis), the batch split over every device of
every process (:mod:`minsubdt_jax.parallel`); an orbax checkpoint follows each chunk; every ``--eval-every`` steps
and at the end all seeds are evaluated in one rollout program. The run directory holds ``config.json``,
``dataset.json``, ``metrics.jsonl`` (loss per chunk, evaluations), ``results.json``, ``learning_curve.png`` and
``checkpoints/``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from typing import Callable

import jax
import numpy as np
import orbax.checkpoint as ocp

from .agents import preset_config
from .agents.base import make_train_chunk, merge_losses, piece_steps
from .caches import enable_compilation_cache
from .config import CHOICES, PRESETS, Config, validate
from .costs import describe_metrics
from .flags import add_flags, load_fields
from .loggers import Loggers, logger_names
from .loop import chunk_loop
from .methods import RETURNS_ALIASES
from .parallel import gather, replicate
from .rundir import RunLock, exit_code, json_text, truncate_metrics
from .runresults import METRICS_FILE_JSONL, finish_run, periodic_eval
from .runsetup import ModelData, RunPlan, Started, Trained, plan_run, prepare_models, start_run


def train(cfg: Config, resume: bool = False, verbose: bool = True,
          progress_fn: Callable[[int, dict], None] | None = None, metrics=None) -> dict:
    """Run one training job end to end in ``cfg.run_dir()``; returns the contents of ``results.json``.

    One model per method of ``cfg.methods`` and seed (``cfg.seed ...``, ``cfg.seeds`` of them), method-major, trains
    in one program: they share the dataset and the agent, and differ in their return tokens and seeds. In a
    multi-process job (``cfg.num_processes``) every process calls this, and only process 0 writes the run directory
    (checkpoints are written jointly by orbax). ``progress_fn(step, record)`` (as brax's) receives every record
    written to ``metrics.jsonl``: the loss after each chunk and each evaluation's scores (lists over the models).
    ``metrics`` (names or :class:`~minsubdt_jax.costs.CostMetric`, a user's own) replace ``cfg.costs`` as the cost
    metrics; ``results.json`` names them (``dataset.cost_metrics``). A resumed run needs the same ones again.

    The stages: :func:`plan_run` (every check before anything is written), :func:`prepare_models` (the data of each
    model), :func:`start_run` (the run's files, the agent and its state), :func:`train_loop` (chunks, checkpoints,
    periodic evaluation) and :func:`finish_run` (the final evaluation and ``results.json``); the run directory is
    locked against a second writer from its first write to its end."""
    lock = RunLock()
    try:
        run = plan_run(cfg, resume, verbose, metrics)
        models = prepare_models(run, metrics)
        started = start_run(run, lock)
        state, data = replicate((started.state, models.data), run.mesh)
        started, models = dataclasses.replace(started, state=state), dataclasses.replace(models, data=data)
        log, loggers = _logger(run, started.start, progress_fn)
        trained = train_loop(run, started, models, log)
        return finish_run(run, started, trained, models, log, loggers)
    finally:
        lock.release()


def _logger(run: RunPlan, start: int, progress_fn):
    """``(log, loggers)``: ``log(record)`` appends to ``metrics.jsonl`` (cut back to ``start`` first), sends to the
    loggers and to ``progress_fn``."""
    metrics_path = os.path.join(run.out, METRICS_FILE_JSONL)
    if run.main:
        truncate_metrics(metrics_path, start)
    loggers = (Loggers(logger_names(run.cfg.logger), run.out, dataclasses.asdict(run.cfg),
                       [mo.label for mo in run.models]) if run.main else None)

    def log(record):
        if run.main:
            with open(metrics_path, "a") as f:
                f.write(json_text(record) + "\n")
            loggers.log(record)
        if progress_fn is not None:
            progress_fn(record["step"], record)

    return log, loggers


def train_loop(run: RunPlan, started: Started, models: ModelData, log) -> Trained:
    """Chunks of ``cfg.chunk_steps`` steps until ``cfg.steps`` (:func:`~minsubdt_jax.loop.chunk_loop`: Ctrl-C stops
    after the current chunk's checkpoint), each in ~10 dispatches so the bar moves, its loss logged, an evaluation
    every ``cfg.eval_every`` steps, a checkpoint after each."""
    cfg, agent, tx, mngr = run.cfg, started.agent, started.tx, started.mngr
    state, data, data_axis = started.state, models.data, models.data_axis
    chunks, t0 = {}, time.time()

    def chunk(step, bar):
        nonlocal state
        n = min(cfg.chunk_steps, cfg.steps - step)
        m = piece_steps(n, agent.whole_chunks)
        if m not in chunks:
            if run.verbose and not chunks:
                bar.write("compiling the train step (the first chunk waits for it) ...")
            chunks[m] = make_train_chunk(agent, tx, run.batch_size, m, run.mesh, seed_axis=True, data_axis=data_axis,
                                         ema_decay=cfg.ema_decay)
        tc, pieces = time.time(), []
        for _ in range(n // m):  # the same steps as one scan of n (the state carries rng and step); the bar moves
            state, piece = chunks[m](state, data)
            pieces.append(jax.block_until_ready(piece))
            bar.update(m)
        losses, parts = merge_losses(pieces)  # [n, S]; a critic agent's losses by name beside
        per_model = np.asarray(gather(losses)).mean(0)  # [models]
        if not np.isfinite(per_model).all():
            last = f"the last checkpoint is step {step}" if step else "no checkpoint was written"
            raise ValueError(f"training diverged: non-finite loss {per_model.tolist()} in steps {step + 1}-"
                             f"{step + n} (not checkpointed; {last}); try a lower --learning-rate")
        step += n
        log({"step": step, "loss": float(per_model.mean()), "loss_per_model": per_model.tolist(),
             **({"loss_parts": {k: float(np.mean(gather(v))) for k, v in parts.items()}} if parts else {}),
             "chunk_seconds": time.time() - tc})
        if cfg.eval_every and step % cfg.eval_every == 0 and step < cfg.steps:
            log(periodic_eval(run, agent, state, step, models.per_model))
        bar.set_postfix(loss=f"{per_model.mean():.4f}")
        return step

    def save(step, stopping):
        mngr.save(step, args=ocp.args.StandardSave(state))

    resume = f"python -m minsubdt_jax.train --config {os.path.join(run.out, 'config.json')} --resume"
    step = chunk_loop(started.start, cfg.steps, chunk, save, resume=resume, verbose=run.verbose)
    return Trained(state, step, time.time() - t0)


def parse_args(argv=None) -> tuple[Config, bool]:
    """``(config, resume)`` from the command line: the preset's values, overridden by the flags given."""
    p = argparse.ArgumentParser(prog="python -m minsubdt_jax.train",
                                description="Train MinSubDT (or DT, BC, a critic agent) on a dataset and evaluate it in "
                                            "batched physics: C MuJoCo on a CPU, MJX on an accelerator.")
    add_flags(p, Config, CHOICES, PRESETS, Config.preset, aliases={"learning_rate": ("--lr",)})
    p.add_argument("--config", help="a config file (a run's config.json, or YAML) to start from; its fields "
                   "override the preset's and the flags given override its")
    p.add_argument("--returns", choices=tuple(RETURNS_ALIASES),
                   help="older name of --method: " + ", ".join(f"{k} = {v}" for k, v in RETURNS_ALIASES.items()))
    p.add_argument("--resume", action="store_true", help="continue from the run directory's last checkpoint")
    args = vars(p.parse_args(argv))
    if args["costs"] == "list":  # as the data CLI: the built-in metrics of --env, then exit
        print("\n".join(describe_metrics(args["env"] or Config.env)))
        raise SystemExit(0)
    resume = args.pop("resume")
    alias = args.pop("returns")
    if alias is not None:
        if args["method"] not in (None, RETURNS_ALIASES[alias]):
            raise ValueError(f"--returns {alias} means --method {RETURNS_ALIASES[alias]}, not {args['method']}: "
                             f"give one of them")
        args["method"] = RETURNS_ALIASES[alias]
    path = args.pop("config")
    from_file = load_fields(path, Config, "python -m minsubdt_jax.train --help") if path else {}
    preset = args["preset"] or from_file.get("preset") or Config.preset
    given = {k: v for k, v in args.items() if v is not None}
    method = given.get("method") or from_file.get("method") or Config.method
    cfg = dataclasses.replace(preset_config(preset, method), **{**from_file, **given})
    return validate(cfg), resume


def main(argv=None) -> int:
    enable_compilation_cache()
    return exit_code(lambda: train(*parse_args(argv)))


if __name__ == "__main__":
    sys.exit(main())
