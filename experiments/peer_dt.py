"""Our Decision Transformer beside d3rlpy's, trained on the same file at our preset's settings (issue 54).

    python3 -m venv .venv-peer && .venv-peer/bin/pip install -e . d3rlpy==2.8.1 torch   # not our dependencies
    .venv-peer/bin/python experiments/peer_dt.py run --env hopper --dataset medium-expert [--seeds 3 --peer-seeds 1]
    .venv-peer/bin/python experiments/peer_dt.py time [--steps 200]   # both training steps, one after the other
    python experiments/peer_dt.py report                              # results/peer_dt.md from the committed JSON

``run`` records (or reuses) our dataset, trains d3rlpy 2.8's ``DecisionTransformer`` on it with our ``--preset``'s
model and optimiser (linear state embedding, width, layers, heads, context, batch, dropout 0.1 everywhere, AdamW
with weight decay on every parameter, global-norm clip, returns / 1000, standardised states), our schedule (linear
warm-up then cosine to 0, a small ``LRSchedulerFactory``) and our parameter average (EMA min(d, (1+t)/(10+t)),
kept in ``fit``'s per-step callback: d3rlpy has none). It evaluates that average in our gymnasium env
(``minsubdt/<Env>-brax-v0``), one episode at a time through d3rlpy's ``StatefulTransformerWrapper`` (reset seeds
10000 + i), conditioned on the file's best episode return, scored with our references. Our DT trains on the same
file as ``python -m minsubdt_jax.train --method dt --preset P --seeds S`` (resumed if its run directory exists) and
is evaluated as every run is. Writes ``experiments/results/peer_dt/<env>-<dataset>-<preset>.json``.

What d3rlpy fixes and we cannot match (``../docs/convergence.md``, *The DT against a peer*): its loss sums over action
dimensions and divides by B*K including padding; its windows end at a uniformly drawn step; state std + 1e-3; its
LayerNorm epsilon. Torch threads: as many as the machine's cores (2 here), as XLA uses.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import subprocess
import sys
import time

import numpy as np
from minsubdt_jax.atomic import write_atomic
from minsubdt_jax.rundir import per_model

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results", "peer_dt")


def _cfg(a):
    from minsubdt_jax.agents import preset_config
    cfg = preset_config(a.preset, "dt")
    return dataclasses.replace(cfg, steps=a.steps or cfg.steps)


def _lr_factor(cfg, step: int) -> float:
    """Our schedule (``agents.base.learning_rate``) over its peak, at 0-based ``step``."""
    from minsubdt_jax.agents.base import learning_rate
    return float(learning_rate(cfg, step)) / cfg.learning_rate


def d3rlpy_config(cfg):
    """d3rlpy's ``DecisionTransformerConfig`` at our config's settings."""
    import d3rlpy
    from torch.optim.lr_scheduler import LambdaLR

    @dataclasses.dataclass()
    class OurSchedule(d3rlpy.optimizers.LRSchedulerFactory):
        def create(self, optim):
            return LambdaLR(optim, lambda step: _lr_factor(cfg, step))

        @staticmethod
        def get_type() -> str:
            return "minsubdt_warmup_cosine"

    optim = d3rlpy.optimizers.AdamWFactory(weight_decay=cfg.weight_decay, clip_grad_norm=cfg.grad_clip,
                                           lr_scheduler_factory=OurSchedule())
    return d3rlpy.algos.DecisionTransformerConfig(
        batch_size=cfg.batch_size, learning_rate=cfg.learning_rate, context_size=cfg.context_len,
        max_timestep=cfg.episode_length, num_heads=cfg.n_heads, num_layers=cfg.n_layers,
        attn_dropout=cfg.dropout, resid_dropout=cfg.dropout, embed_dropout=cfg.dropout, optim_factory=optim,
        encoder_factory=d3rlpy.models.VectorEncoderFactory([cfg.embed_dim], exclude_last_activation=True),
        observation_scaler=d3rlpy.preprocessing.StandardObservationScaler(),
        reward_scaler=d3rlpy.preprocessing.MultiplyRewardScaler(1 / 1000),
        position_encoding_type=d3rlpy.PositionEncodingType.SIMPLE)


def d3rlpy_dataset(data):
    """Our ``Trajectories`` as d3rlpy's ``MDPDataset``: flat steps, each episode closed by a terminal or a timeout."""
    import d3rlpy
    valid = data.valid_mask()
    last = np.zeros(valid.shape, bool)
    last[np.arange(len(data.lengths)), data.lengths - 1] = True
    term = last & data.terminals[:, None]
    return d3rlpy.dataset.MDPDataset(
        data.observations[valid], data.actions[valid], data.rewards[valid].astype(np.float32),
        term[valid].astype(np.float32), (last & ~data.terminals[:, None])[valid].astype(np.float32))


def train_d3rlpy(cfg, buffer, seed: int):
    """d3rlpy's DT trained for ``cfg.steps`` with our EMA; returns ``(algo, ema_state_dict, seconds)``."""
    import d3rlpy
    import torch

    from minsubdt_jax.agents.base import ema_decay_at
    d3rlpy.seed(seed)
    algo = d3rlpy_config(cfg).create(device="cpu:0")
    ema = {}

    def average(algo, epoch, total_step):
        t = total_step - 1  # the 0-based step just taken
        d = float(ema_decay_at(t, cfg.ema_decay)) if cfg.ema_decay else 0.0  # ours, per step
        with torch.no_grad():
            for k, v in algo.impl.modules.transformer.state_dict().items():
                ema[k] = v.detach().clone() if k not in ema or not v.is_floating_point() else d * ema[k] + (1 - d) * v

    t0 = time.perf_counter()
    algo.fit(buffer, n_steps=cfg.steps, n_steps_per_epoch=cfg.steps, show_progress=False, save_interval=10**9,
             experiment_name=f"peer-dt-s{seed}", logger_adapter=d3rlpy.logging.NoopAdapterFactory(), callback=average)
    return algo, ema, time.perf_counter() - t0


def evaluate_d3rlpy(algo, params, env: str, target: float, episodes: int) -> dict:
    """``episodes`` episodes of ``algo`` with ``params`` loaded, one at a time in our gymnasium env."""
    import gymnasium as gym

    import minsubdt_jax.envs.gym_env  # noqa: F401  (registers minsubdt/*)
    from minsubdt_jax.envs.gym_env import IDS
    from minsubdt_jax.envs.spec import env_spec
    from minsubdt_jax.references import normalized_score
    algo.impl.modules.transformer.load_state_dict(params)
    g = gym.make(IDS[(env_spec(env).name, "brax")])
    returns, lengths = [], []
    for i in range(episodes):
        actor, (obs, _), reward, done, total, n = algo.as_stateful_wrapper(target), g.reset(seed=10_000 + i), 0.0, \
            False, 0.0, 0
        while not done:
            obs, reward, term, trunc, _ = g.step(actor.predict(obs, reward))
            total, n, done = total + reward, n + 1, term or trunc
        returns.append(total), lengths.append(n)
    score = normalized_score(env, np.array(returns))
    return {"normalized_score_mean": float(score.mean()), "normalized_score_std": float(score.std()),
            "length_mean": float(np.mean(lengths)), "episodes": episodes}


def train_ours(a, cfg) -> dict:
    """Our DT on the same file and settings, ``--seeds`` models in one program (resumed if started)."""
    out = a.ours_out or os.path.join("runs", "peer", f"{a.env}-{a.dataset}-{a.preset}-dt")
    path = os.path.join(out, "results.json")
    if not os.path.exists(path):
        cmd = [sys.executable, "-m", "minsubdt_jax.train", "--env", a.env, "--dataset", a.dataset, "--method", "dt",
               "--preset", a.preset, "--steps", str(cfg.steps), "--seeds", str(a.seeds), "--out", out]
        subprocess.run(cmd + (["--resume"] if os.path.exists(os.path.join(out, "config.json")) else []), check=True)
    res = json.load(open(path))
    return {"run_dir": out, "seeds": [{"normalized_score_mean": e["normalized_score_mean"],
                                       "normalized_score_std": e["normalized_score_std"],
                                       "length_mean": e.get("length_mean")} for e in per_model(res)]}


def run(a) -> dict:
    import d3rlpy
    import torch

    from minsubdt_jax.data import resolve_dataset
    torch.set_num_threads(os.cpu_count())
    cfg = _cfg(a)
    f = resolve_dataset(a.env, a.dataset)
    path = os.path.join(RESULTS, f"{a.env}-{a.dataset}-{a.preset}.json")
    out = json.load(open(path)) if os.path.exists(path) else {"peer": {}}
    out.update(env=a.env, dataset=a.dataset, preset=a.preset, steps=cfg.steps, sha256=f.sha256[:12],
               target_return=float(f.data.returns.max()), d3rlpy=d3rlpy.__version__, torch=torch.__version__)
    buffer = d3rlpy_dataset(f.data)
    for seed in range(a.peer_seeds):
        if str(seed) in out["peer"]:
            continue  # resumable: a finished seed is kept
        algo, ema, secs = train_d3rlpy(cfg, buffer, seed)
        out["peer"][str(seed)] = dict(evaluate_d3rlpy(algo, ema, a.env, out["target_return"], a.episodes),
                                      train_seconds=secs)
        os.makedirs(RESULTS, exist_ok=True)
        write_atomic(path, json.dumps(out, indent=1))
        print(json.dumps({"seed": seed, **out["peer"][str(seed)]}), flush=True)
    out["ours"] = train_ours(a, cfg)
    write_atomic(path, json.dumps(out, indent=1))
    return out


def time_steps(a) -> dict:
    """Seconds per training step of both DTs at ``--preset``, one model each, one after the other on this machine:
    d3rlpy's ``update`` (with its batch sampling) and our jitted step (sampling included, ``lax.scan`` chunks)."""
    import d3rlpy
    import torch

    from minsubdt_jax.agents.base import make_optimizer
    from minsubdt_jax.agents.dt.agent import make_dt_agent
    from minsubdt_jax.data import resolve_dataset
    torch.set_num_threads(os.cpu_count())
    cfg = _cfg(a)
    d = resolve_dataset(a.env, a.dataset).data
    buffer = d3rlpy_dataset(d)
    algo = d3rlpy_config(cfg).create(device="cpu:0")
    algo.fit(buffer, n_steps=20, n_steps_per_epoch=20, show_progress=False, save_interval=10**9,
             experiment_name="peer-dt-time", logger_adapter=d3rlpy.logging.NoopAdapterFactory())
    t0 = time.perf_counter()
    for _ in range(a.steps):
        algo.update(buffer.sample_trajectory_batch(cfg.batch_size, length=cfg.context_len))
    peer = (time.perf_counter() - t0) / a.steps
    agent, tx = make_dt_agent(cfg, d.observations.shape[-1], d.actions.shape[-1], cfg.episode_length), make_optimizer(cfg)
    ours = ours_seconds_per_step(agent, tx, cfg.batch_size, d, a.steps)
    out = {"preset": a.preset, "steps": a.steps, "d3rlpy_s_per_step": peer, "ours_s_per_step": ours,
           "ratio": peer / ours, "cores": os.cpu_count(), "torch_threads": torch.get_num_threads()}
    os.makedirs(RESULTS, exist_ok=True)
    write_atomic(os.path.join(RESULTS, f"time-{a.preset}.json"), json.dumps(out, indent=1))
    print(json.dumps(out))
    return out


def ours_seconds_per_step(agent, tx, batch_size: int, d, steps: int) -> float:
    """Seconds per step of our jitted training (sampling included, one scanned chunk of ``steps``) of ``agent`` on
    the episodes ``d``, after a chunk that compiles it."""
    import jax

    from minsubdt_jax.agents.base import init_state
    from minsubdt_jax.data import sampler_data
    chunk = agent.make_chunk(tx, batch_size, steps)
    data = sampler_data(d, d.rewards, *d.state_stats())
    state = jax.block_until_ready(chunk(init_state(agent, tx, jax.random.PRNGKey(0)), data)[0])  # compile
    t0 = time.perf_counter()
    jax.block_until_ready(chunk(state, data))
    return (time.perf_counter() - t0) / steps


def report(a) -> str:
    """``results/peer_dt.md``: per file, the peer's and our scores per seed and their means."""
    rows = ["| file | preset | d3rlpy DT (per seed) | ours (per seed) | d3rlpy mean | ours mean |", "|---|---|---|---|---|---|"]
    for name in sorted(os.listdir(RESULTS)):
        r = json.load(open(os.path.join(RESULTS, name)))
        if name.startswith("time-") or "ours" not in r:
            continue
        peer = [r["peer"][s]["normalized_score_mean"] for s in sorted(r["peer"])]
        ours = [s["normalized_score_mean"] for s in r["ours"]["seeds"]]
        fmt = lambda xs: ", ".join(f"{x:.1f}" for x in xs)  # noqa: E731
        rows.append(f"| {r['env']} {r['dataset']} ({r['sha256']}) | {r['preset']} | {fmt(peer)} | {fmt(ours)} | "
                    f"{np.mean(peer):.1f} ± {np.std(peer):.1f} | {np.mean(ours):.1f} ± {np.std(ours):.1f} |")
    text = ("# Our DT beside d3rlpy's on the same file\n\n`.venv-peer/bin/python experiments/peer_dt.py run --env E "
            "--dataset D --seeds 3`, then `python experiments/peer_dt.py report`. Normalised scores, mean over 100 "
            "episodes per seed, target = the file's best return; mean ± std over seeds.\n\n" + "\n".join(rows) + "\n")
    for name in sorted(n for n in os.listdir(RESULTS) if n.startswith("time-")):
        t = json.load(open(os.path.join(RESULTS, name)))
        text += (f"\nTraining step at `{t['preset']}` on this {t['cores']}-core CPU (one model, {t['steps']} steps, "
                 f"`peer_dt.py time`): d3rlpy {1e3 * t['d3rlpy_s_per_step']:.1f} ms, ours "
                 f"{1e3 * t['ours_s_per_step']:.1f} ms: {t['ratio']:.2f}x in our favour.\n")
    write_atomic(os.path.join(HERE, "results", "peer_dt.md"), text)
    print(text)
    return text


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("command", choices=("run", "time", "report"))
    p.add_argument("--env", default="hopper")
    p.add_argument("--dataset", default="medium-expert")
    p.add_argument("--preset", default="study")
    p.add_argument("--steps", type=int, default=None, help="training steps (run; default the preset's) or timed steps")
    p.add_argument("--seeds", type=int, default=3, help="our DT's seeds (one program)")
    p.add_argument("--peer-seeds", type=int, default=1, help="d3rlpy's seeds (~10 min each on 2 cores)")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--ours-out", default=None, help="our run's directory (default runs/peer/<env>-<dataset>-<preset>-dt)")
    a = p.parse_args(argv)
    if a.command != "report" and not all(importlib.util.find_spec(m) for m in ("torch", "d3rlpy")):
        p.error("needs torch and d3rlpy, which are not our dependencies: make their venv with 'python3 -m venv "
                ".venv-peer && .venv-peer/bin/pip install -e . d3rlpy==2.8.1 torch' and run this with "
                ".venv-peer/bin/python (README, *Our DT against d3rlpy's*)")
    if a.command == "time":
        a.steps = a.steps or 200
    {"run": run, "time": time_steps, "report": report}[a.command](a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
