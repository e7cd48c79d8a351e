"""Training configuration: one dataclass, presets, and a CLI where every field is a flag."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass

from .costs import check_costs
from .envs import DYNAMICS, ENVS, PHYSICS
from .loggers import logger_names
from .methods import METHODS
from .parallel import distributed_settings


@dataclass(frozen=True)
class Config:
    """Every field is a ``--flag`` of ``python -m minsubdt_jax.train`` (underscores become dashes)."""

    env: str = "walker"  # hopper | walker | halfcheetah
    # a named dataset (see minsubdt_jax.data.NAMED_DATASETS) or a D4RL .hdf5 path; several, comma-separated, train
    # in one program (one env's: every model draws only its own dataset's episodes)
    dataset: str = "medium"
    # minsubdt | minsubdt-learned | dt | dt-total | dt-tied | minsubdt-vec | dt-vec | modt-p | morvs-p | bc-p | bc |
    # bc-mlp | iql | td3bc | cql |
    # brac-v | bear | awr | minsubdt-iql | minsubdt-td3bc | minsubdt-iql-spread | minsubdt-td3bc-spread | minsubdt-cql |
    # minsubdt-brac-v | minsubdt-bear | minsubdt-awr: see
    # minsubdt_jax.methods (--returns subdom|learned|true|none still names the first four). Several,
    # comma-separated, train in one program (they must share an agent)
    method: str = "minsubdt"
    seed: int = 0  # training and evaluation seed (the first one, with --seeds)
    seeds: int = 1  # train seeds seed, seed+1, ..., seed+seeds-1 as one program (vmapped in one jitted step)
    dataset_seed: int = 0  # seed of a recorded named dataset (the data stays fixed across training seeds)
    steps: int = 3000  # gradient steps
    # quick (the default: a first model in ~4 min on 2 cores) | smoke (seconds, tests) | cpu (<= 15 min here) | study
    # (Table 1's, chosen from score curves: docs/convergence.md) | paper (the DT paper's model, 100k steps)
    preset: str = "quick"
    out: str | None = None  # run directory; default runs/{env}-{dataset}-{returns}-s{seed}
    # DT (DT paper: K=20, 128, 3 layers, 1 head, dropout 0.1)
    context_len: int = 20  # K, the context length in timesteps
    embed_dim: int = 128  # the transformer's width
    n_layers: int = 3  # transformer blocks
    n_heads: int = 1  # attention heads
    dropout: float = 0.1  # dropout rate in training
    # MLP policy (--method bc-mlp)
    mlp_hidden: int = 256  # hidden width of the MLP policy (--method bc-mlp)
    mlp_layers: int = 2  # hidden layers of the MLP policy
    # critic agents (--method iql | td3bc | cql | minsubdt-iql | ...): unset values take the agent's reference's
    critic_batch_size: int = 256  # transitions per gradient step of a critic agent (all three references: 256)
    discount: float = 0.99  # gamma of the critics' backup
    tau: float = 0.005  # Polyak rate of the target networks
    ac_hidden: int | None = None  # hidden width of the critics, value net and actor; default 256, BRAC-v's critics 300
    ac_layers: int | None = None  # their hidden layers; default IQL and TD3+BC 2, CQL 3 (CORL)
    # Adam rate of the actor (and CQL's temperature); default 3e-4, CQL 3e-5 (CORL), BRAC-v 3e-5
    actor_lr: float | None = None
    critic_lr: float | None = None  # Adam rate of the critics and IQL's value net; default 3e-4, BRAC-v 1e-3
    iql_expectile: float = 0.7  # IQL's expectile tau of the value loss (CORL's hopper medium-expert: 0.5)
    iql_beta: float = 3.0  # IQL's inverse temperature of the advantage weights (CORL's hopper medium-expert: 6)
    td3bc_alpha: float = 2.5  # TD3+BC's alpha: the actor maximises lambda Q with lambda = alpha / mean |Q|
    cql_alpha: float = 10.0  # CQL's conservative weight (CORL's; the CQL paper's README: 5 or 10)
    cql_actions: int = 10  # CQL's sampled actions per kind (uniform, pi(s), pi(s')) in the logsumexp
    brac_alpha: float = 0.1  # BRAC-v's fixed weight of the KL value penalty (the reference's example command)
    # steps of a critic agent's first stage: BRAC-v's behaviour policy (default --steps / 5), BEAR's MMD-only
    # warm-up (default --steps / 25: the reference's 40k of 1M)
    pretrain_steps: int | None = None
    # BEAR's MMD kernel, laplacian | gaussian; unset: the agent's choice for the env (its reference's: gaussian for
    # halfcheetah, laplacian otherwise; minsubdt_jax.agents.AGENTS["bear"].data_settings)
    bear_kernel: str | None = None
    # optimisation (DT paper: AdamW 1e-4, wd 1e-4, 10k warm-up steps, clip 0.25, batch 64)
    learning_rate: float = 1e-4  # AdamW's peak learning rate
    weight_decay: float = 1e-4  # AdamW's weight decay
    warmup_steps: int = 10000  # linear warm-up of the learning rate over these steps
    grad_clip: float = 0.25  # global-norm gradient clip
    batch_size: int = 64  # sequences per gradient step (split over --devices)
    # matmul precision of the DT and the critic agents: f32 | tf32 (TF32 matmuls on GPUs that have them; the same as
    # f32 on a CPU) | bf16 (bfloat16 matmuls; parameters, optimiser, LayerNorms, network outputs and losses float32)
    precision: str = "f32"
    # after the warm-up: constant (DT paper) | cosine (decays to 0 at --steps, as IQL's actor; --steps is then fixed)
    lr_schedule: str = "constant"
    # > 0: keep an exponential moving average of the parameters (decay min(d, (1 + t) / (10 + t)) at step t) and
    # evaluate it; periodic evaluations also score the raw parameters (eval_raw_* in metrics.jsonl)
    ema_decay: float = 0.0
    # returns
    rtg_scale: float | None = None  # divides returns-to-go; default 1000 for true returns, 1 for subdom
    target_return: float | None = None  # eval conditioning; default 0 for subdom, max dataset return for true
    beta: float = 1.0  # subdominance margin (eq. 1), same for every feature
    # cost metrics, comma-separated (minsubdt_jax.costs.METRICS: x_velocity, fall, energy, height_steadiness,
    # uprightness, speed_band[:LO:HI], joint_speed); default the env's: x_velocity, and fall for hopper and walker
    costs: str | None = None
    eval_costs: str | None = None  # more cost metrics to report on the rollouts (not trained on), comma-separated
    alpha_max: float | None = None  # optional cap on alpha in eq. 2
    # learned costs (--returns learned, seed eq. 3)
    cost_dim: int = 2  # K', the number of learned cost features
    cost_steps: int = 1000  # Adam steps on preference pairs
    cost_pairs: int = 32  # preference pairs per step
    cost_label_noise: float = 0.0  # probability of flipping a preference label
    # data and evaluation
    episode_length: int = 1000  # horizon of generated datasets, of evaluation, and of the cost average
    # size of a recorded named dataset; default D4RL's (1M; medium-replay hopper 402k, walker 302k, halfcheetah
    # 202k; medium-expert twice 1M)
    dataset_transitions: int | None = None
    # physics: auto (C MuJoCo on a CPU, MJX on an accelerator or a mesh of several devices) | mujoco | mjx
    physics: str = "auto"
    physics_threads: int = 0  # C MuJoCo's threads (0: the machine's cores)
    # env rules to evaluate in: brax | d4rl (gym's v2-v4 rules and XMLs, D4RL's references); default from the data:
    # our recordings brax, a D4RL file by replaying its recorded states (--check-dynamics), else d4rl
    dynamics: str | None = None
    eval_episodes: int = 10  # 0 skips the final evaluation
    eval_every: int = 0  # evaluate every this many steps during training (0: only at the end); multiple of chunk_steps
    eval_episodes_periodic: int = 10  # episodes per seed of each periodic evaluation
    chunk_steps: int = 500  # steps per jitted lax.scan chunk; a checkpoint and a log line after each
    # besides metrics.jsonl: tensorboard (tensorboardX, <out>/tensorboard) | wandb (the [wandb] extra; WANDB_MODE=offline
    # keeps it local), comma-separated
    logger: str | None = None
    devices: int = 0  # data parallel over this many local devices (0: all); --batch-size must divide evenly
    # several processes (jax.distributed); unset: from JAX_COORDINATOR_ADDRESS / JAX_NUM_PROCESSES /
    # JAX_PROCESS_ID, else one process. Every process runs the same command; process 0 writes the run directory
    coordinator_address: str | None = None  # host:port of process 0's coordinator
    num_processes: int | None = None  # processes in the job
    process_id: int | None = None  # this process's index, 0 .. num_processes - 1

    def run_dir(self) -> str:
        if self.out:
            return self.out
        name = "+".join(d.rsplit("/", 1)[-1].removesuffix(".hdf5") for d in self.datasets)
        seeds = f"{self.seed}" if self.seeds == 1 else f"{self.seed}-{self.seed + self.seeds - 1}"
        return f"runs/{self.env}-{name}-{'+'.join(self.methods)}-s{seeds}"

    @property
    def datasets(self) -> tuple[str, ...]:
        """The datasets of ``--dataset`` (one, or several comma-separated)."""
        return tuple(d.strip() for d in self.dataset.split(","))

    @property
    def methods(self) -> tuple[str, ...]:
        """The method names of ``--method`` (one, or several comma-separated)."""
        return tuple(m.strip() for m in self.method.split(","))

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)


PRESETS = {
    # seconds: for tests and a first look
    "smoke": Config(preset="smoke", steps=20, context_len=5, embed_dim=32, n_layers=1, batch_size=8,
                    warmup_steps=10, learning_rate=1e-3, chunk_steps=10, episode_length=100,
                    dataset_transitions=2000, eval_episodes=3, eval_episodes_periodic=3, cost_steps=20),
    # trains and evaluates one dataset in <= 15 min on a 2-core CPU (an evaluation every 500 steps: a score curve)
    "cpu": Config(preset="cpu", steps=3000, embed_dim=64, n_layers=2, warmup_steps=500, learning_rate=3e-4,
                  chunk_steps=500, eval_episodes=10, eval_every=500, cost_steps=500),
    # the default: study's recipe over 3k steps (a peak rate of 1e-3, warm-up 300, cosine to 0 at 3k, EMA 0.999),
    # evaluated on 30 episodes: a first model that has learned (walker medium: at or above the data's own average,
    # README), recording included in ~4 min on 2 idle cores
    "quick": Config(preset="quick", steps=3000, embed_dim=64, n_layers=2, warmup_steps=300, learning_rate=1e-3,
                    lr_schedule="cosine", ema_decay=0.999, chunk_steps=500, eval_episodes=30, eval_every=0,
                    cost_steps=500),
    # chosen from score curves to be affordable on a 2-core CPU (issue 25; docs/convergence.md says which cells
    # have flattened at it): the cpu model at a peak rate of 1e-3 (3e-4 left DT rising on two cells), a cosine
    # decay to 0 over 10k steps and an average of the parameters (EMA 0.999), evaluated on 100 episodes; ~5-8 min
    # per model here
    "study": Config(preset="study", steps=10_000, embed_dim=64, n_layers=2, warmup_steps=500, learning_rate=1e-3,
                    lr_schedule="cosine", ema_decay=0.999, chunk_steps=500, eval_episodes=100, eval_every=0),
    # the DT paper's hyper-parameters (~14 h on a 2-core CPU)
    "paper": Config(preset="paper", steps=100_000, chunk_steps=1000, eval_episodes=100, eval_every=10_000),
}

# the fields that say where and how a run was trained, not what was trained: a result that differs from another
# only in these is the same experiment (programs of several models, chunking, periodic curves, and who steps the
# same equations: C MuJoCo or MJX, README "Physics"). Every other field changes a model's result, but for the
# fields of agents it is not (minsubdt_jax.agents: AgentInfo.fields, result_fields)
RUN_ONLY_FIELDS = frozenset({"env", "dataset", "method", "seed", "seeds", "out", "preset", "chunk_steps", "physics",
                             "physics_threads", "logger", "devices", "coordinator_address", "num_processes",
                             "process_id", "eval_every", "eval_episodes_periodic"})


LR_SCHEDULES = ("constant", "cosine")
CHOICES = {"env": tuple(ENVS), "preset": tuple(PRESETS), "physics": PHYSICS,
           "dynamics": DYNAMICS, "lr_schedule": LR_SCHEDULES, "precision": ("f32", "tf32", "bf16"),
           "bear_kernel": ("laplacian", "gaussian")}


# The range of each bounded number: (kind, low, high, the range as its error says it), high None: no upper bound.
# kind: "closed" [low, high], "open" (low, high), "half" [low, high), "open-closed" (low, high]. A field that may
# be None (unset: the agent's own default) is checked when set.
_POSITIVE = ("steps", "context_len", "embed_dim", "n_layers", "n_heads", "batch_size", "chunk_steps", "episode_length",
             "learning_rate", "beta", "warmup_steps", "cost_dim", "cost_steps", "cost_pairs", "seeds", "mlp_hidden",
             "mlp_layers", "eval_episodes_periodic", "critic_batch_size", "iql_beta", "td3bc_alpha", "cql_actions",
             "grad_clip", "dataset_transitions", "ac_hidden", "ac_layers", "actor_lr", "critic_lr", "rtg_scale",
             "alpha_max")
RANGES = {
    **{name: ("open", 0, None, "> 0") for name in _POSITIVE},
    **{name: ("closed", 0, None, ">= 0") for name in ("eval_episodes", "weight_decay", "cql_alpha", "brac_alpha",
                                                        "seed", "dataset_seed")},
    "physics_threads": ("closed", 0, None, ">= 0 (0: all cores)"),
    "devices": ("closed", 0, None, ">= 0 (0: all local devices)"),
    "dropout": ("half", 0, 1, "in [0, 1)"),
    "ema_decay": ("half", 0, 1, "in [0, 1) (0: off)"),
    "cost_label_noise": ("half", 0, 0.5, "in [0, 0.5)"),
    "discount": ("closed", 0, 1, "in [0, 1]"),
    "iql_expectile": ("open", 0, 1, "in (0, 1)"),
    "tau": ("open-closed", 0, 1, "in (0, 1]"),
}


def _in_range(v, kind: str, lo, hi) -> bool:
    low_ok = lo is None or (v > lo if kind in ("open", "open-closed") else v >= lo)
    high_ok = hi is None or (v <= hi if kind in ("closed", "open-closed") else v < hi)
    return low_ok and high_ok


def validate(cfg: Config) -> Config:
    """Raise ValueError with one clear message on an unusable config; return it unchanged otherwise."""
    for f in dataclasses.fields(cfg):  # NaN or inf in any number (--target-return nan ran and wrote NaN scores)
        if isinstance(getattr(cfg, f.name), float) and not math.isfinite(getattr(cfg, f.name)):
            raise ValueError(f"--{f.name.replace('_', '-')} must be a finite number, got {getattr(cfg, f.name)}")
    _check_names(cfg)
    for name, (kind, lo, hi, says) in RANGES.items():
        v = getattr(cfg, name)
        if v is not None and not _in_range(v, kind, lo, hi):
            raise ValueError(f"--{name.replace('_', '-')} must be {says}, got {v}")
    if cfg.context_len > cfg.episode_length:
        raise ValueError(f"--context-len {cfg.context_len} is longer than an episode (--episode-length "
                         f"{cfg.episode_length})")
    if cfg.eval_every < 0 or cfg.eval_every % cfg.chunk_steps:
        raise ValueError(f"--eval-every must be 0 or a multiple of --chunk-steps ({cfg.chunk_steps}), got {cfg.eval_every}")
    if cfg.embed_dim % cfg.n_heads:
        raise ValueError(f"--embed-dim ({cfg.embed_dim}) must be divisible by --n-heads ({cfg.n_heads})")
    if cfg.pretrain_steps is not None and not 0 <= cfg.pretrain_steps < cfg.steps:
        raise ValueError(f"--pretrain-steps must be in [0, --steps), got {cfg.pretrain_steps}")
    distributed_settings(cfg.coordinator_address, cfg.num_processes, cfg.process_id)
    return cfg


def _check_names(cfg: Config) -> None:
    """The settings that name things: choices, methods (one agent, one kind of return token), datasets, cost
    metrics, loggers."""
    for name, allowed in CHOICES.items():
        allowed = tuple(ENVS) if name == "env" else allowed  # with any registered since (envs.register_env)
        unset = name in ("dynamics", "bear_kernel") and getattr(cfg, name) is None  # the data's, the agent's
        if getattr(cfg, name) not in allowed and not unset:
            raise ValueError(f"--{name.replace('_', '-')} must be one of {list(allowed)}, got {getattr(cfg, name)!r}")
    bad = [m for m in cfg.methods if m not in METHODS]
    if bad or len(set(cfg.methods)) != len(cfg.methods):
        raise ValueError(f"--method must be one or several (comma-separated, each once) of {list(METHODS)}, "
                         f"got {cfg.method!r}")
    agents = {METHODS[m].agent for m in cfg.methods}
    if "" in cfg.datasets or len(set(cfg.datasets)) != len(cfg.datasets):
        raise ValueError(f"--dataset must be one or several (comma-separated, each once) datasets, got {cfg.dataset!r}")
    if len(agents) > 1:
        raise ValueError(f"methods trained in one program must share an agent; {cfg.method!r} mixes {sorted(agents)}")
    if len({METHODS[m].vector for m in cfg.methods}) > 1 or len({METHODS[m].preference for m in cfg.methods}) > 1:
        raise ValueError(f"--method {cfg.method}: a return token per metric and one return token, or states with and "
                         f"without a preference, make two different models: train them apart")
    if cfg.costs is not None:
        check_costs(cfg.env, cfg.costs)  # one error on an unknown name or a metric the env cannot compute
    logger_names(cfg.logger)
    if cfg.eval_costs is not None:
        check_costs(cfg.env, cfg.eval_costs, "--eval-costs")
