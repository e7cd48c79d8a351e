"""The models of one training program: their sampler arrays stacked, and their evaluation.

One program trains M models (datasets x methods x seeds, dataset-major) vmapped in one jitted step
(:mod:`minsubdt_jax.train`). Models on one dataset share its states and actions and differ in their return tokens
(a method's rewards, learned costs per seed). Models on several datasets of one env train on the datasets'
episodes concatenated (padded to the longest episode), each model drawing only its own dataset's episodes (its
sampling weights are 0 elsewhere; :func:`~minsubdt_jax.data.draw_episodes`), so each model sees the batches its
single-dataset run would. Each is evaluated against its own dataset's demonstrations.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .agents.base import PolicyInputs
from .costs import cost_metrics
from .scoring import Scoring, evaluate_policy
from .methods import Method
from .parallel import available_bytes, replicate
from .pipeline import Prepared


@dataclass(frozen=True)
class Model:
    """One model of a program: its method and seed, and its dataset where the program trains several (else None)."""

    method: Method
    seed: int
    dataset: str | None = None

    @property
    def label(self) -> str:
        """``[<dataset>-]<method>-s<seed>``: its name in loggers and plots."""
        return (f"{self.dataset}-" if self.dataset else "") + f"{self.method.name}-s{self.seed}"

    def record(self) -> dict:
        """Its entry in ``results.json``'s ``models`` (and every evaluation's summary)."""
        return {**({"dataset": self.dataset} if self.dataset else {}), "method": self.method.name, "seed": self.seed}


def program_models(methods: list[Method], seeds: list[int], datasets: tuple[str, ...]) -> list[Model]:
    """The models of a program, dataset-major then method-major: one per (dataset,) method and seed."""
    several = len(datasets) > 1
    return [Model(m, s, d if several else None) for d in datasets for m in methods for s in seeds]


PER_MODEL_FIELDS = ("returns_to_go", "rewards", "last_done")  # what a method's data changes: its rewards
SHARED_FIELDS = ("states", "actions", "lengths")  # a dataset's own (its weights are per model over several)


def distinct_sources(per_model: list[Prepared]) -> list:
    """The models' datasets (:class:`~minsubdt_jax.data.DatasetFile`), in their order of first appearance."""
    out = []
    for p in per_model:
        if not any(p.source is s for s in out):
            out.append(p.source)
    return out


def stack_models(per_model: list[Prepared]):
    """``(data, data_axis)`` for the train chunk. One model, or models that share one :class:`Prepared`: its
    sampler arrays, ``data_axis None``. Several on one dataset: the shared arrays, with the per-model fields (return
    tokens ``[M, N, T]``, rewards ``[M, N, T]``, ``last_done [M, N]``) stacked and a ``data_axis`` that maps only
    those. Several datasets: their episodes concatenated along N (``T`` padded to the longest), the per-model
    fields and the sampling ``weights [M, N]`` stacked, each model's zero outside its own dataset's rows."""
    first = per_model[0].sampler
    if all(p is per_model[0] for p in per_model):
        return first, None
    sources = distinct_sources(per_model)
    if len(sources) == 1:
        data = first.replace(**{k: jnp.stack([getattr(p.sampler, k) for p in per_model]) for k in PER_MODEL_FIELDS})
        return data, jax.tree.map(lambda _: None, first).replace(**{k: 0 for k in PER_MODEL_FIELDS})
    own = [next(p.sampler for p in per_model if p.source is s) for s in sources]  # a sampler per dataset
    T = max(d.states.shape[1] for d in own)
    sizes = [d.states.shape[0] for d in own]
    starts = np.concatenate([[0], np.cumsum(sizes)])

    def pad_t(x):  # [N, t, ...] -> [N, T, ...]
        return jnp.pad(x, [(0, 0), (0, T - x.shape[1])] + [(0, 0)] * (x.ndim - 2)) if x.ndim > 1 else x

    def placed(p, key):  # this model's field on the rows of its own dataset, zeros elsewhere
        i = next(j for j, s in enumerate(sources) if p.source is s)
        x = pad_t(getattr(p.sampler, key))
        return jnp.pad(x, [(int(starts[i]), int(starts[-1] - starts[i + 1]))] + [(0, 0)] * (x.ndim - 1))

    shared = {k: jnp.concatenate([pad_t(getattr(d, k)) for d in own]) for k in SHARED_FIELDS}
    mapped = PER_MODEL_FIELDS + ("weights",)
    data = first.replace(**shared, **{k: jnp.stack([placed(p, k) for p in per_model]) for k in mapped})
    return data, jax.tree.map(lambda _: None, first).replace(**{k: 0 for k in mapped})


def evaluate_models(cfg, agent, params, models: list, per_model: list[Prepared], mesh, episodes: int, *,
                    physics: str = "auto", dynamics: str = "brax") -> list[dict]:
    """Evaluate the M trained models (``params [M, ...]``, ``models``: their :class:`Model` records) on
    ``episodes`` episodes each, in one batched program per dataset (``physics``; in MJX the episodes split over
    ``mesh``) under ``dynamics``, against that dataset's demonstrations; a model of seed s has its
    episodes seeded ``s + 10000``. One summary dict per model, with its method and seed (and dataset)."""
    sources = distinct_sources(per_model)
    if len(sources) > 1:
        out = [None] * len(models)
        for src in sources:
            idx = [i for i, p in enumerate(per_model) if p.source is src]
            sub = jax.tree.map(lambda x: x[np.asarray(idx)], params)
            evs = evaluate_models(cfg, agent, sub, [models[i] for i in idx], [per_model[i] for i in idx], mesh,
                                  episodes, physics=physics, dynamics=dynamics)
            for i, ev in zip(idx, evs):
                out[i] = ev
        return out
    stack = lambda get: np.stack([np.asarray(get(p), np.float32) for p in per_model])  # noqa: E731
    inputs = PolicyInputs(params=params, state_mean=stack(lambda p: p.state_mean),
                          state_std=stack(lambda p: p.state_std), target_return=stack(lambda p: p.target_return),
                          rtg_scale=stack(lambda p: p.rtg_scale),
                          subtract_rewards=np.array([mo.method.subtract_rewards for mo in models], np.float32),
                          preference=None if per_model[0].preference is None else stack(lambda p: p.preference))
    learned = [p.learned for p in per_model] if any(p.learned for p in per_model) else None
    scoring = Scoring(demo_costs=per_model[0].costs, beta=cfg.beta, alpha_max=cfg.alpha_max, learned=learned,
                      demo_features=[p.features for p in per_model] if learned else None, metrics=per_model[0].metrics,
                      extra_metrics=cost_metrics(cfg.env, cfg.eval_costs) if cfg.eval_costs else (), dynamics=dynamics,
                      references=per_model[0].references)
    evs = evaluate_policy(cfg.env, agent, replicate(inputs, mesh), num_episodes=episodes, horizon=cfg.episode_length,
                          seeds=[mo.seed + 10_000 for mo in models], scoring=scoring, mesh=mesh, physics=physics,
                          threads=cfg.physics_threads)
    return [dict(ev.summary(), **mo.record(), target_return=np.asarray(p.target_return).tolist(),
                 **({} if p.preference is None else {"preference": np.asarray(p.preference).tolist()}))
            for ev, mo, p in zip(evs, models, per_model)]


def eval_record(step: int, per_model: list[dict], final: bool = False) -> dict:
    """The ``metrics.jsonl`` record of one evaluation: per model, its method and seed (and dataset, over several),
    and the mean and the standard deviation over its episodes of the normalised score, min-subdominance and
    return."""
    rec = {"step": step, "eval_episodes": per_model[0]["episodes"], "final": final,
           "eval_method": [e["method"] for e in per_model], "eval_seed": [e["seed"] for e in per_model]}
    if "dataset" in per_model[0]:
        rec["eval_dataset"] = [e["dataset"] for e in per_model]
    for key in ("normalized_score", "min_subdominance", "return"):
        rec[f"eval_{key}"] = [e[f"{key}_mean"] for e in per_model]
        rec[f"eval_{key}_std"] = [e[f"{key}_std"] for e in per_model]
    return rec


def check_memory(cfg, agent, n_models: int, n_devices: int) -> None:
    """A configuration whose train step cannot fit in memory (the DT's: a long context, a huge batch) is one error
    here, before anything is written, not an out-of-memory kill without a message (``agent``: its
    :class:`~minsubdt_jax.agents.AgentInfo`, whose ``step_bytes`` estimates it)."""
    have = available_bytes()
    need = agent.step_bytes(cfg, n_models) / n_devices if agent.step_bytes is not None else 0
    if have is not None and need > have:
        raise ValueError(f"one train step of {n_models} model(s) at --context-len {cfg.context_len}, --batch-size "
                         f"{cfg.batch_size}, --embed-dim {cfg.embed_dim}, --n-layers {cfg.n_layers} needs ~"
                         f"{need / 2 ** 30:.1f} GiB per device, more than the {have / 2 ** 30:.1f} GiB available: "
                         f"lower --context-len or --batch-size (or train fewer models per program)")
