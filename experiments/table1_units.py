"""Table 1's units: which runs (env x dataset x method x seed) are missing, grouped into the programs that train
them, and a program's results split into one compact file per model (``experiments/table1.py``)."""

from __future__ import annotations

import dataclasses
import json
import os

from minsubdt_jax.agents import AGENTS, missing_presets, result_fields
from minsubdt_jax.methods import METHODS as ALL_METHODS
from minsubdt_jax.rundir import per_model


def run_name(env, dataset, method, seed) -> str:
    return f"{env}-{dataset}-{method}-s{seed}"


def check_critic_settings(preset: str, methods) -> None:
    """Raise ValueError if a method of ``methods`` has no setting of its own at ``preset`` where the preset gives
    agents their own (``AgentInfo.presets``, ``minsubdt_jax.agents``): the DT family's would be no result."""
    unset = missing_presets(preset, methods)
    if unset:
        raise ValueError(f"--preset {preset} has no setting for {', '.join(unset)}: no score curve has shown its "
                         f"agent flat within ~10 CPU-minutes per model here (docs/convergence.md); it waits for a GPU")


def plan_units(envs, datasets, methods, seeds, result_path, whole_env=False):
    """``(units, skipped)``: the programs that train the runs without a result file (``result_path(env, dataset,
    method, seed)``), and the names of those with one. A unit is ``(first seed, datasets, env, methods, seeds)``:
    in each env x dataset, the methods of one agent missing the same seeds, a run of consecutive missing seeds
    each. With ``whole_env`` the env's datasets that miss the same seeds of the same methods are one unit
    (``--dataset a,b,c``: issue 23's whole env in one program), except for an agent that needs a program per
    dataset (``AgentInfo.one_dataset``: AWR). The lowest missing seed of every cell goes first
    (stable: datasets, envs, methods)."""
    units, skipped = [], []
    for d in datasets:
        for e in envs:
            groups = {}  # (missing seeds, agent) -> the methods missing exactly them (in the order asked)
            for m in methods:
                have = [s for s in seeds if os.path.exists(result_path(e, d, m, s))]
                skipped += [run_name(e, d, m, s) for s in have]
                missing = tuple(sorted(set(seeds) - set(have)))
                if missing:
                    groups.setdefault((missing, ALL_METHODS[m].agent), []).append(m)
            for (missing, _), ms in groups.items():
                units += [(first, (d,), e, tuple(ms), n) for first, n in seed_runs(missing)]
    if whole_env:
        merged = {}  # (env, methods, first, n) -> datasets, in the order asked (AWR's datasets stay apart)
        for first, (d,), e, ms, n in units:
            alone = AGENTS[ALL_METHODS[ms[0]].agent].one_dataset
            merged.setdefault((e, ms, first, n) + ((d,) if alone else ()), []).append(d)
        units = [(key[2], tuple(ds), key[0], key[1], key[3]) for key, ds in merged.items()]
    units.sort(key=lambda t: t[0])
    return units, skipped


def compact(results: dict) -> dict:
    """The part of ``train``'s results.json that the table needs, floats rounded (small files to commit)."""
    def rnd(x):
        if isinstance(x, float):
            return round(x, 5)
        if isinstance(x, list):
            return [rnd(v) for v in x]
        if isinstance(x, dict):
            return {k: rnd(v) for k, v in x.items()}
        return x

    keep = ("config", "method", "dataset", "train", "eval", "references", "platform", "physics", "curve", "dt_revision")
    return rnd({k: results[k] for k in keep if k in results})


def seed_runs(seeds) -> list[tuple[int, int]]:
    """Sorted seeds -> ``(first, count)`` runs of consecutive seeds, each one ``--seeds count`` program."""
    runs = []
    for s in sorted(set(seeds)):
        if runs and runs[-1][0] + runs[-1][1] == s:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
        else:
            runs.append((s, 1))
    return runs


def model_results(res: dict, i: int) -> dict:
    """Model ``i`` of a run's results (one of its methods x seeds), shaped as that model's single run would report
    them: its method and seed in the config, its own data summary and evaluation."""
    model = res["models"][i] if "models" in res else {"method": res["config"]["method"], "seed": res["config"]["seed"]}
    out = {k: v for k, v in res.items() if k not in ("seeds", "models", "methods", "eval_per_model", "eval_per_seed", "eval_by_method",
                                                        "dataset_per_model")}
    out["config"] = dict(res["config"], method=model["method"], seed=model["seed"], seeds=1,
                         dataset=model.get("dataset", res["config"]["dataset"]))
    if "dataset_per_model" in res:
        own = res["dataset_per_model"][i]  # over several datasets it has its own demos' sample
        out["dataset"] = dict(own, costs_sample=own.get("costs_sample", res["dataset"].get("costs_sample", [])))
    if per_model(res) is not None:
        out["eval"] = per_model(res)[i]
    return out


def stale_fields(saved: dict, expected) -> dict:
    """``{field: (saved, expected)}`` for each config field that changes a model's result whose value in a result
    file's ``config`` (``saved``) is not the one the sweep would train with now (``expected``: a ``Config``). A
    field the file predates counts at its default (the code before it behaved so). Only the fields that change the
    agent's results are compared (``minsubdt_jax.agents.result_fields``: not where or how it ran, nor other agents'
    settings)."""
    compared = result_fields(ALL_METHODS[expected.method].agent)
    out = {}
    for f in dataclasses.fields(expected):
        want, default = getattr(expected, f.name), f.default
        have = saved.get(f.name, default)
        if f.name in compared and have != want:
            out[f.name] = (have, want)
    return out


def check_not_stale(result_path, cells, expected) -> None:
    """Raise ValueError, before anything is trained or written, if a result file that the sweep would skip as
    done (``result_path(env, dataset, method, seed)`` for ``cells``) was trained with another config than the
    sweep's now (``expected(method)``: a ``Config``; :func:`stale_fields`): a changed preset must not keep its
    old results under its name."""
    stale = []
    for e, d, m, s in cells:
        if os.path.exists(p := result_path(e, d, m, s)):
            with open(p) as f:
                saved = json.load(f)
            diff = {"config": ("not recorded", "...")} if "config" not in saved else stale_fields(saved["config"],
                                                                                                 expected(m))
            revision = AGENTS[ALL_METHODS[m].agent].revision  # another revision of the model's code: not this result
            if revision is not None and saved.get("dt_revision", 1) != revision:
                diff["dt_revision"] = (saved.get("dt_revision", 1), revision)
            stale += [f"{run_name(e, d, m, s)}: " + ", ".join(f"{k} {a!r} (now {b!r})" for k, (a, b) in diff.items())
                      ] if diff else []
    if stale:
        folder = os.path.dirname(result_path(*cells[0]))
        raise ValueError(f"{len(stale)} result file(s) in {folder} were trained with another config than this "
                         f"sweep's, and would be kept as its results: {'; '.join(stale[:3])}"
                         f"{' ...' if len(stale) > 3 else ''}. Move them aside (git mv {folder} <folder>-<what "
                         f"differs>) or delete them, then run again")
