"""Table 1's units: which runs (env x dataset x method x seed) are missing, grouped into the programs that train
them, and a program's results split into one compact file per model (``experiments/table1.py``)."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess

import numpy as np

from minsubdt_jax.agents import AGENTS, missing_presets, result_fields
from minsubdt_jax.methods import METHODS as ALL_METHODS


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


def per_seed_results(res: dict, i: int) -> dict:
    """Model ``i`` of a run's results (one of its methods x seeds), shaped as that model's single run would report
    them: its method and seed in the config, its own data summary and evaluation."""
    model = res["models"][i] if "models" in res else {"method": res["config"]["method"], "seed": res["config"]["seed"]}
    out = {k: v for k, v in res.items() if k not in ("seeds", "models", "methods", "eval_per_seed", "eval_by_method",
                                                        "dataset_per_model")}
    out["config"] = dict(res["config"], method=model["method"], seed=model["seed"], seeds=1,
                         dataset=model.get("dataset", res["config"]["dataset"]))
    if "dataset_per_model" in res:
        own = res["dataset_per_model"][i]  # over several datasets it has its own demos' sample
        out["dataset"] = dict(own, costs_sample=own.get("costs_sample", res["dataset"].get("costs_sample", [])))
    if "eval_per_seed" in res:
        out["eval"] = res["eval_per_seed"][i]
    return out


def commit_results(paths: list[str], message: str) -> None:
    """``git commit`` exactly ``paths`` (a finished unit's result files) with ``message``, in the repository that
    holds them, leaving any other change in the work tree as it is (``table1.py run --commit``: a long sweep's
    results land in the history as they finish)."""
    cwd = os.path.dirname(os.path.abspath(paths[0]))
    rel = [os.path.relpath(os.path.abspath(p), cwd) for p in paths]
    subprocess.run(["git", "add", "--", *rel], cwd=cwd, check=True, capture_output=True)
    subprocess.run(["git", "commit", "-q", "-m", message, "--", *rel], cwd=cwd, check=True, capture_output=True)


def model_curve(run_dir: str, model: dict) -> dict | None:
    """One model's training curve from its program's ``metrics.jsonl`` (``model``: its ``method``, ``seed`` and,
    over several datasets, ``dataset``, as in results.json's ``models``): the evaluations' steps, normalised score
    and min-subdominance (means over their episodes; ``final`` marks the last), and its training loss per logged
    step. Kept in the model's result file, so a landed cell's curves outlive the machine that trained it; ``None``
    where the run directory has no evaluation."""
    from minsubdt_jax.rundir import read_metrics

    rows = read_metrics(os.path.join(run_dir, "metrics.jsonl"))
    evals = [r for r in rows if "eval_normalized_score" in r]
    if not evals:
        return None
    r0 = evals[0]
    k = next((i for i, (m, s) in enumerate(zip(r0["eval_method"], r0["eval_seed"]))
              if m == model["method"] and s == model["seed"]
              and ("eval_dataset" not in r0 or r0["eval_dataset"][i] == model.get("dataset"))), None)
    if k is None:
        raise ValueError(f"{run_dir}: metrics.jsonl evaluates no model {model} (another program's run directory?)")
    losses = [r for r in rows if "loss_per_seed" in r]
    return {"step": [r["step"] for r in evals], "final": [bool(r.get("final", False)) for r in evals],
            "normalized_score": [r["eval_normalized_score"][k] for r in evals],
            "min_subdominance": [r["eval_min_subdominance"][k] for r in evals],
            "loss_step": [r["step"] for r in losses], "loss": [r["loss_per_seed"][k] for r in losses]}


def curves_from_results(rows: list[dict]) -> dict:
    """:func:`minsubdt_jax.plot.curves`' dict from the ``curve`` of committed result files (``rows``: one cell's,
    from ``table1.load_results``): per method, the mean and std over its seeds at each evaluation step."""
    have = [r for r in rows if r["r"].get("curve")]
    if len({_schedule(r) for r in have}) > 1:
        raise ValueError("curves_from_results: these result files come from programs with different evaluation or "
                         "loss steps; split them with programs_of first")
    out = {"score": {}, "min_subdominance": {}}
    steps, loss = have[0]["r"]["curve"]["loss_step"], np.array([r["r"]["curve"]["loss"] for r in have], float)
    out["loss"] = (np.array(steps), loss.mean(0), loss.std(0))
    for method in dict.fromkeys(r["method"] for r in have):
        cs = [r["r"]["curve"] for r in have if r["method"] == method]
        for key, name in (("normalized_score", "score"), ("min_subdominance", "min_subdominance")):
            v = np.array([c[key] for c in cs], float)
            out[name][method] = (np.array(cs[0]["step"]), v.mean(0), v.std(0), np.array(cs[0]["final"]))
    return out


def _schedule(row: dict) -> tuple:
    c = row["r"]["curve"]
    return tuple(c["step"]), tuple(c["loss_step"])


def programs_of(rows: list[dict]) -> dict[str, list[dict]]:
    """One cell's result rows with a ``curve``, grouped by their evaluation and loss steps (the DT family's 10k
    steps and each critic agent's own schedule cannot share one mean), each group labelled by its methods:
    ``{"iql": [...], "td3bc": [...]}``, the input for one :func:`curves_from_results` each. Two programs of the
    same methods on other schedules keep apart, the second labelled with its evaluation steps too."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        if r["r"].get("curve"):
            groups.setdefault(_schedule(r), []).append(r)
    out: dict[str, list[dict]] = {}
    for (steps, _), g in groups.items():
        label = "+".join(dict.fromkeys(r["method"] for r in g))
        out[label if label not in out else f"{label} (evaluated at {list(steps)})"] = g
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
