"""Our critic agents beside d3rlpy's (TD3+BC, IQL, CQL, BEAR), trained on the same file at our settings (issue 72).

    python3 -m venv .venv-peer && .venv-peer/bin/pip install -e . d3rlpy==2.8.1 torch   # not our dependencies
    .venv-peer/bin/python experiments/peer_critics.py run --agent td3bc --env hopper --dataset medium [--seeds 3]
    .venv-peer/bin/python experiments/peer_critics.py run --agent cql --env hopper --dataset medium --steps 20000 \
        --seeds 2 --eval-every 5000                    # a budget both sides afford here, score points on both sides
    .venv-peer/bin/python experiments/peer_critics.py time --agent iql   # both training steps, one after the other
    python experiments/peer_critics.py report          # results/peer_critics.md from the committed JSON

``run`` records (or reuses) our dataset and trains, seed by seed, d3rlpy 2.8's agent on it with our agent's
settings read from our agent's own record at ``--preset`` (``agents.preset_config`` -> ``make_agent``: widths,
depths, rates, batch, discount, Polyak rate, the agent's loss weights), our state standardisation and IQL's reward
scaling (x 1000 / (max - min episode return)), and our parameter average (EMA min(d, (1+t)/(10+t)) of every
network, kept in ``fit``'s per-step callback: d3rlpy has none). It evaluates that average in our gymnasium env
(``minsubdt/<Env>-brax-v0``, reset seeds 10000 + i, all episodes stepped together), deterministically as ours
(BEAR: the best of 100 samples by the first critic, d3rlpy's ``predict`` as ours), scored with our references.
Ours trains on the same file as ``python -m minsubdt_jax.train --method M --preset P --seeds S`` (one program,
resumed if its run directory exists). Each finished d3rlpy seed is written at once (the run resumes by seed):
``experiments/results/peer_critics/<agent>-<env>-<dataset>-<steps>.json``.

What d3rlpy fixes and we cannot match: its initialisation (torch's default uniform, ours flax's lecun-normal
kernels), Adam's epsilon (1e-8 both, but torch's in the square root's sum), its transitions (a time-out's last step
is kept and bootstraps from its own observation; ours leaves it out), its update order (IQL: critics and V first,
then the actor, each on its own step's networks; ours one backward pass, a lag of one step), CQL's entropy term in
the backup (ours has none, CORL's) and its Lagrange-free alpha of 0 learning rate, BEAR's actor entropy term (ours
none) and its MMD on post-tanh VAE actions.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

from peer_dt import d3rlpy_dataset, ours_seconds_per_step  # beside this file (a script's folder is on its path)

from peer_critics_report import RESULTS, report  # beside this file
METHOD = {"td3bc": "td3bc", "iql": "iql", "cql": "cql", "bear": "bear"}  # our method on the true reward


def our_config(a):
    """Our run's config at ``--preset`` (the agent's own values over it), ``--steps`` if given."""
    import dataclasses

    from minsubdt_jax.agents import preset_config
    cfg = preset_config(a.preset, METHOD[a.agent])
    return dataclasses.replace(cfg, env=a.env, dataset=a.dataset, steps=a.steps or cfg.steps)


def our_agent(cfg, obs_dim: int, act_dim: int):
    from minsubdt_jax.agents import make_agent
    return make_agent(METHOD[cfg.method], cfg, obs_dim, act_dim, cfg.episode_length)


def d3rlpy_config(agent_name: str, ours):
    """d3rlpy's config of ``agent_name`` at the settings of ``ours`` (our agent's record)."""
    import d3rlpy
    enc = d3rlpy.models.VectorEncoderFactory(list(ours.hidden))
    common = dict(batch_size=ours.batch_size, gamma=ours.discount, tau=ours.tau, actor_encoder_factory=enc,
                  critic_encoder_factory=enc, actor_learning_rate=ours.actor_lr,
                  critic_learning_rate=ours.critic_lr,
                  observation_scaler=d3rlpy.preprocessing.StandardObservationScaler())
    if agent_name == "td3bc":
        return d3rlpy.algos.TD3PlusBCConfig(alpha=ours.alpha, target_smoothing_sigma=0.2, target_smoothing_clip=0.5,
                                            update_actor_interval=2, **common)
    if agent_name == "iql":
        actor_optim = d3rlpy.optimizers.AdamFactory(
            lr_scheduler_factory=d3rlpy.optimizers.CosineAnnealingLRFactory(T_max=ours.steps))
        return d3rlpy.algos.IQLConfig(expectile=ours.expectile, weight_temp=ours.beta, max_weight=100.0,
                                      value_encoder_factory=enc, actor_optim_factory=actor_optim,
                                      reward_scaler=d3rlpy.preprocessing.ReturnBasedRewardScaler(multiplier=1000.0),
                                      **common)
    if agent_name == "cql":
        return d3rlpy.algos.CQLConfig(temp_learning_rate=ours.actor_lr, alpha_learning_rate=0.0,
                                      conservative_weight=ours.cql_alpha, n_action_samples=ours.n_actions, **common)
    if agent_name == "bear":
        return d3rlpy.algos.BEARConfig(
            imitator_learning_rate=ours.vae_lr, alpha_learning_rate=ours.dual_lr, temp_learning_rate=0.0,
            initial_temperature=1e-20, imitator_encoder_factory=d3rlpy.models.VectorEncoderFactory(list(ours.vae_hidden)),
            mmd_sigma=20.0, mmd_kernel=ours.kernel, n_mmd_action_samples=4, alpha_threshold=0.05,
            n_target_samples=10, n_action_samples=100, warmup_steps=ours.warmup, **common)
    raise ValueError(f"--agent must be one of {list(METHOD)}, got {agent_name!r}")


class Average:
    """Our EMA of every d3rlpy network's floating parameters, updated after each step (``fit``'s callback)."""

    def __init__(self, algo, decay: float):
        import torch
        self.decay, self.torch = decay, torch
        self.modules = [m for m in vars(algo.impl.modules).values() if isinstance(m, torch.nn.Module)]
        self.params = [p for m in self.modules for p in m.state_dict().values() if p.is_floating_point()]
        self.ema = [p.detach().clone() for p in self.params]

    def __call__(self, algo, epoch, total_step):
        from minsubdt_jax.agents.base import ema_decay_at
        d = float(ema_decay_at(total_step - 1, self.decay))  # the 0-based step just taken
        with self.torch.no_grad():
            self.torch._foreach_mul_(self.ema, d)
            self.torch._foreach_add_(self.ema, [p.detach() for p in self.params], alpha=1.0 - d)

    def swapped(self):
        """Swap the average into the networks (and the raw parameters out); calling it again swaps back."""
        with self.torch.no_grad():
            for p, e in zip(self.params, self.ema):
                tmp = p.detach().clone()
                p.copy_(e)
                e.copy_(tmp)


def evaluate(predict, env: str, episodes: int) -> dict:
    """``episodes`` episodes of ``predict(obs [B, obs]) -> [B, act]`` in our gymnasium env, all stepped together."""
    import gymnasium as gym

    from minsubdt_jax.envs.gym_env import IDS
    from minsubdt_jax.envs.spec import env_spec
    from minsubdt_jax.references import normalized_score
    envs = [gym.make(IDS[(env_spec(env).name, "brax")]) for _ in range(episodes)]
    obs = np.stack([g.reset(seed=10_000 + i)[0] for i, g in enumerate(envs)])
    returns, lengths, alive = np.zeros(episodes), np.zeros(episodes, int), np.ones(episodes, bool)
    while alive.any():
        idx = np.flatnonzero(alive)
        acts = predict(obs[idx].astype(np.float32))
        for j, i in enumerate(idx):
            obs[i], r, term, trunc, _ = envs[i].step(acts[j])
            returns[i], lengths[i] = returns[i] + r, lengths[i] + 1
            alive[i] = not (term or trunc)
    score = normalized_score(env, returns)
    return {"normalized_score_mean": float(score.mean()), "normalized_score_std": float(score.std()),
            "length_mean": float(lengths.mean()), "episodes": episodes}


def train_d3rlpy(a, cfg, ours, buffer, seed: int) -> dict:
    """One d3rlpy seed at ``cfg`` with our EMA; its final score and, every ``--eval-every`` steps, a curve point."""
    import d3rlpy
    d3rlpy.seed(seed)
    algo = d3rlpy_config(a.agent, ours).create(device="cpu:0")
    algo.build_with_dataset(buffer)
    average, curve = Average(algo, cfg.ema_decay), []

    def callback(algo, epoch, total_step):
        average(algo, epoch, total_step)
        if total_step % 10_000 == 0:  # progress in the lane's log
            print(f"d3rlpy {a.agent} seed {seed}: step {total_step} of {cfg.steps}, {time.perf_counter() - t0:.0f} s",
                  flush=True)
        if a.eval_every and total_step % a.eval_every == 0 and total_step < cfg.steps:
            average.swapped()
            curve.append({"step": total_step, **evaluate(algo.predict, a.env, a.eval_episodes)})
            average.swapped()

    t0 = time.perf_counter()
    algo.fit(buffer, n_steps=cfg.steps, n_steps_per_epoch=cfg.steps, show_progress=False, save_interval=10**9,
             experiment_name=f"peer-{a.agent}-s{seed}", logger_adapter=d3rlpy.logging.NoopAdapterFactory(),
             callback=callback)
    secs = time.perf_counter() - t0
    average.swapped()
    return dict(evaluate(algo.predict, a.env, a.episodes), train_seconds=secs, curve=curve)


def train_ours(a, cfg) -> dict:
    """Our agent on the same file and settings, ``--seeds`` models in one program (resumed if started)."""
    from minsubdt_jax.rundir import per_model

    out = a.ours_out or os.path.join("runs", "peer-critics", name_of(a, cfg))
    path = os.path.join(out, "results.json")
    if not os.path.exists(path):
        cmd = [sys.executable, "-m", "minsubdt_jax.train", "--env", a.env, "--dataset", a.dataset, "--method",
               METHOD[a.agent], "--preset", a.preset, "--steps", str(cfg.steps), "--seeds", str(a.seeds),
               "--eval-episodes", str(a.episodes), "--out", out]
        if a.eval_every:
            cmd += ["--eval-every", str(a.eval_every), "--eval-episodes-periodic", str(a.eval_episodes),
                    "--chunk-steps", str(math.gcd(a.eval_every, cfg.chunk_steps))]
        subprocess.run(cmd + (["--resume"] if os.path.exists(os.path.join(out, "config.json")) else []), check=True)
    res = json.load(open(path))
    curve = []
    if a.eval_every:
        with open(os.path.join(out, "metrics.jsonl")) as f:
            curve = [{"step": r["step"], "normalized_score_mean": r["eval_normalized_score"]}
                     for r in map(json.loads, filter(str.strip, f)) if "eval_normalized_score" in r
                     and r["step"] < cfg.steps]
    return {"run_dir": out, "curve": curve,
            "seeds": [{k: e.get(k) for k in ("normalized_score_mean", "normalized_score_std", "length_mean")}
                      for e in per_model(res)]}


def name_of(a, cfg) -> str:
    return f"{a.agent}-{a.env}-{a.dataset}-{cfg.steps}"


def save(out: dict, path: str) -> None:
    from minsubdt_jax.atomic import write_atomic
    write_atomic(path, json.dumps(out, indent=1))


def run(a) -> dict:
    import d3rlpy
    import torch

    from minsubdt_jax.data import resolve_dataset
    torch.set_num_threads(a.threads)
    cfg = our_config(a)
    f = resolve_dataset(a.env, a.dataset)
    ours = our_agent(cfg, f.data.observations.shape[-1], f.data.actions.shape[-1])
    path = os.path.join(RESULTS, name_of(a, cfg) + ".json")
    out = json.load(open(path)) if os.path.exists(path) else {"peer": {}}
    if out.get("sha256", f.sha256[:12]) != f.sha256[:12]:
        raise SystemExit(f"error: {path} was trained on another recording ({out['sha256']}); this machine's file is "
                         f"{f.sha256[:12]}: move it aside to start again")
    command = " ".join([".venv-peer/bin/python experiments/peer_critics.py run", *sys.argv[2:]])
    out.update(agent=a.agent, env=a.env, dataset=a.dataset, preset=a.preset, steps=cfg.steps, sha256=f.sha256[:12],
               ema_decay=cfg.ema_decay, eval_every=a.eval_every, d3rlpy=d3rlpy.__version__,
               torch=torch.__version__, command=out.get("command", command))
    buffer = d3rlpy_dataset(f.data)
    os.makedirs(RESULTS, exist_ok=True)
    for seed in range(a.peer_seeds if a.peer_seeds is not None else a.seeds):
        if str(seed) in out["peer"]:
            continue  # resumable: a finished seed is kept
        out["peer"][str(seed)] = train_d3rlpy(a, cfg, ours, buffer, seed)
        save(out, path)
        if a.commit:  # a seed of the peer's is hours on this CPU: it lands as it finishes
            from gitcommit import commit_results
            commit_results([path], f"Peer critics (issue 72): d3rlpy {a.agent} {a.env} {a.dataset} seed {seed}; resume: "
                                   f"bash experiments/queue.sh peers")
        print(json.dumps({"seed": seed, **{k: v for k, v in out["peer"][str(seed)].items() if k != "curve"}}),
              flush=True)
    out["ours"] = train_ours(a, cfg)
    save(out, path)
    return out


def time_steps(a) -> dict:
    """Seconds per training step of both agents at ``--preset``, one model each, one after the other on this
    machine: d3rlpy's ``update`` (with its batch sampling) and our jitted step (sampling included, a scanned chunk)."""
    import d3rlpy
    import torch

    from minsubdt_jax.data import resolve_dataset
    torch.set_num_threads(a.threads)
    cfg = our_config(a)
    d = resolve_dataset(a.env, a.dataset).data
    ours = our_agent(cfg, d.observations.shape[-1], d.actions.shape[-1])
    buffer = d3rlpy_dataset(d)
    algo = d3rlpy_config(a.agent, ours).create(device="cpu:0")
    algo.fit(buffer, n_steps=20, n_steps_per_epoch=20, show_progress=False, save_interval=10**9,
             experiment_name="peer-critic-time", logger_adapter=d3rlpy.logging.NoopAdapterFactory())
    t0 = time.perf_counter()
    for _ in range(a.time_steps):
        algo.update(buffer.sample_transition_batch(ours.batch_size))
    peer = (time.perf_counter() - t0) / a.time_steps
    mine = ours_seconds_per_step(ours, ours.optimizer(cfg), ours.batch_size, d, a.time_steps)
    out = {"agent": a.agent, "steps": a.time_steps, "d3rlpy_s_per_step": peer, "ours_s_per_step": mine,
           "ratio": peer / mine, "cores": os.cpu_count(), "torch_threads": torch.get_num_threads()}
    os.makedirs(RESULTS, exist_ok=True)
    save(out, os.path.join(RESULTS, f"time-{a.agent}.json"))
    print(json.dumps(out))
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("command", choices=("run", "time", "report"))
    p.add_argument("--agent", default="td3bc", choices=tuple(METHOD))
    p.add_argument("--env", default="hopper")
    p.add_argument("--dataset", default="medium")
    p.add_argument("--preset", default="study")
    p.add_argument("--steps", type=int, default=None, help="training steps (default the agent's preset's)")
    p.add_argument("--seeds", type=int, default=3, help="our seeds (one program), and d3rlpy's unless --peer-seeds")
    p.add_argument("--peer-seeds", type=int, default=None, help="d3rlpy's seeds (default --seeds)")
    p.add_argument("--episodes", type=int, default=100, help="final evaluation episodes per seed")
    p.add_argument("--eval-every", type=int, default=0, help="a score point every this many steps, both sides")
    p.add_argument("--eval-episodes", type=int, default=30, help="episodes per score point")
    p.add_argument("--threads", type=int, default=1, help="torch threads (1: a lane beside another)")
    p.add_argument("--commit", action="store_true", help="git commit the result file after each d3rlpy seed")
    p.add_argument("--time-steps", type=int, default=500, help="steps timed by 'time'")
    p.add_argument("--ours-out", default=None, help="our run's directory (default runs/peer-critics/<name>)")
    return p


def main(argv=None) -> int:
    p = build_parser()
    a = p.parse_args(argv)
    if a.command != "report" and not all(importlib.util.find_spec(m) for m in ("torch", "d3rlpy")):
        p.error("needs torch and d3rlpy, which are not our dependencies: make their venv with 'python3 -m venv "
                ".venv-peer && .venv-peer/bin/pip install -e . d3rlpy==2.8.1 torch' and run this with "
                ".venv-peer/bin/python")
    {"run": run, "time": time_steps, "report": report}[a.command](a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
