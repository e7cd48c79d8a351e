"""What every agent shares: the train state, the optimiser, one generic train step and its scanned chunk, the
inputs of a rollout policy, and the interface an agent implements.

An agent (``agents/<name>/``, brax-style: ``networks.py``, ``losses.py``, ``agent.py``) is a frozen, hashable
record built from the :class:`~minsubdt_jax.config.Config` and the data's shapes, with:

* ``context_len``: the length of the windows it trains on (:func:`minsubdt_jax.data.sample_batch`);
* ``init_params(key)``: fresh parameters;
* ``policy``: a rollout policy for :func:`minsubdt_jax.envs.make_rollout`, called with :class:`PolicyInputs`;
* ``initial_carry(n)``: the policy's carry for ``n`` fresh episodes;
* ``optimizer(cfg)`` and ``make_chunk(tx, batch_size, n_steps, ...)``: its optimiser and its jitted chunk of
  training steps; ``whole_chunks``: a chunk that cannot be cut into shorter ones (AWR's iteration).

That is what the run calls (:class:`Agent`). Most agents get the last three from :class:`StepAgent`: AdamW and a
``lax.scan`` of the shared step, which minimises the agent's ``loss(params, batch, rng) -> scalar`` on a
:class:`~minsubdt_jax.data.Batch`; the critic agents from :class:`~minsubdt_jax.agents.actor_critic.CriticAgentBase`.
Everything else (sampling, seeds, devices, checkpoints, evaluation) is the same for all agents.
"""

from __future__ import annotations

from typing import Any, Callable, ClassVar, Protocol

import jax
import jax.numpy as jnp
import optax
from flax import struct

from ..data import SamplerData, sample_batch
from ..parallel import shard_batch


@struct.dataclass
class TrainState:
    step: jax.Array
    params: Any
    opt_state: Any
    rng: jax.Array
    ema_params: Any = None  # the parameters' moving average (--ema-decay > 0), else None


def ema_decay_at(step, decay: float):
    """The EMA decay at (0-based) ``step``: ``min(decay, (1 + t) / (10 + t))``, so early averages do not keep the
    initial parameters (TensorFlow's ``ExponentialMovingAverage(num_updates=t)``)."""
    return jnp.minimum(decay, (1.0 + step) / (10.0 + step))


def ema_update(ema, params, step, decay: float):
    """The moving average after ``step``'s update (None when the state keeps none)."""
    if ema is None:
        return None
    d = ema_decay_at(step, decay)
    return jax.tree.map(lambda e, p: d * e + (1.0 - d) * p, ema, params)


def eval_params(state: TrainState):
    """The parameters a run evaluates and reports: the moving average when one is kept, else the raw ones."""
    return state.params if state.ema_params is None else state.ema_params


@struct.dataclass
class PolicyInputs:
    """Traced inputs of a rollout policy: the agent's ``params``, state normalisation ``[obs]`` (``[obs + K]`` with a
    preference), the target return (unscaled), the return scale, and whether rewards are subtracted from the
    return-to-go (1.0 for true returns); for a preference-conditioned method (PEDA's "(P)", ``Method.preference``)
    the preference ``[K]`` its states carry. Policies that do not condition on a return ignore those three."""

    params: Any
    state_mean: jax.Array
    state_std: jax.Array
    target_return: jax.Array
    rtg_scale: jax.Array
    subtract_rewards: jax.Array
    preference: Any = None

    def normalise(self, obs):
        """``obs [..., obs]`` as the model sees a state: the preference appended (if any), then normalised."""
        if self.preference is not None:
            obs = jnp.concatenate([obs, jnp.broadcast_to(self.preference, obs.shape[:-1] + self.preference.shape[-1:])],
                                  -1)
        return (obs - self.state_mean) / self.state_std


class Agent(Protocol):
    """What the run calls of an agent (module docstring)."""

    context_len: int
    policy: Callable
    whole_chunks: bool

    def init_params(self, key) -> Any: ...

    def initial_carry(self, n: int) -> Any: ...

    def optimizer(self, cfg) -> optax.GradientTransformation: ...

    def make_chunk(self, tx, batch_size: int, n_steps: int, mesh=None, *, seed_axis: bool = False,
                   data_axis: int | None = None, ema_decay: float = 0.0) -> Callable: ...


def learning_rate(cfg, step):
    """The rate at (0-based) ``step``: the DT paper's linear warm-up over ``warmup_steps``, then constant, or with
    ``lr_schedule="cosine"`` a cosine decay from the peak at the warm-up's end to 0 at ``steps``."""
    warm = jnp.minimum((step + 1) / cfg.warmup_steps, 1.0)
    if cfg.lr_schedule == "constant":
        return cfg.learning_rate * warm
    frac = jnp.clip((step - cfg.warmup_steps) / max(cfg.steps - cfg.warmup_steps, 1), 0.0, 1.0)
    return cfg.learning_rate * warm * 0.5 * (1.0 + jnp.cos(jnp.pi * frac))


def make_optimizer(cfg) -> optax.GradientTransformation:
    """AdamW at :func:`learning_rate`'s schedule, after global-norm clipping (DT paper)."""
    schedule = lambda step: learning_rate(cfg, step)  # noqa: E731
    return optax.flatten(optax.chain(optax.clip_by_global_norm(cfg.grad_clip),
                                     optax.adamw(schedule, weight_decay=cfg.weight_decay)))


def optimizer_for(agent: Agent, cfg) -> optax.GradientTransformation:
    """The agent's optimiser: :func:`make_optimizer`'s AdamW (:class:`StepAgent`), or a critic agent's per-network
    optimisers (:mod:`~minsubdt_jax.agents.actor_critic`)."""
    return agent.optimizer(cfg)


def init_state(agent: Agent, tx, key, ema: bool = False) -> TrainState:
    """Fresh parameters (from one half of ``key``), optimiser state, and the step rng (the other half); with
    ``ema`` the moving average starts at the parameters."""
    rng, init_rng = jax.random.split(key)
    params = agent.init_params(init_rng)
    return TrainState(step=jnp.zeros((), jnp.int32), params=params, opt_state=tx.init(params), rng=rng,
                      ema_params=jax.tree.map(jnp.copy, params) if ema else None)  # own buffers: both are donated


def make_train_step(agent: Agent, tx, batch_size: int, mesh=None, ema_decay: float = 0.0):
    """Pure ``step(state, data) -> (state, loss)``: sample a batch, forward, backward, clipped AdamW update, and
    the parameters' moving average when the state keeps one (decay :func:`ema_decay_at`).

    With a ``mesh`` (:func:`minsubdt_jax.parallel.make_mesh`) the batch is split over its devices (data
    parallel); the step computes the same thing on any number of devices."""

    def step(state: TrainState, data: SamplerData):
        rng, k_batch, k_drop = jax.random.split(state.rng, 3)
        batch = shard_batch(sample_batch(k_batch, data, batch_size, agent.context_len), mesh)
        loss, grads = jax.value_and_grad(lambda p: agent.loss(p, batch, k_drop))(state.params)
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        ema = ema_update(state.ema_params, params, state.step, ema_decay)
        return TrainState(step=state.step + 1, params=params, opt_state=opt_state, rng=rng, ema_params=ema), loss

    return step


def scan_steps(step, n_steps: int, seed_axis: bool = False, data_axis: int | None = None):
    """Jitted ``chunk(state, data) -> (state, losses [n_steps(, S)])``: ``step`` scanned ``n_steps`` times, ``vmap``-ed
    over a leading seed axis of the state with ``seed_axis`` (``data_axis`` 0: each seed its own sampler data)."""
    if seed_axis:
        step = jax.vmap(step, in_axes=(0, data_axis))

    def chunk(state, data):
        return jax.lax.scan(lambda s, _: step(s, data), state, None, length=n_steps)

    return jax.jit(chunk, donate_argnums=0)


class StepAgent:
    """The run's calls for an agent trained by the shared step (DT, MLP): :func:`make_optimizer`'s AdamW and a scan
    of :func:`make_train_step` on its ``loss``. A subclass with its own step overrides ``make_step`` (the critic
    agents), one whose chunk is no scan of steps ``make_chunk`` and ``whole_chunks``."""

    whole_chunks: ClassVar[bool] = False

    def optimizer(self, cfg) -> optax.GradientTransformation:
        return make_optimizer(cfg)

    def make_step(self, tx, batch_size: int, mesh=None, ema_decay: float = 0.0):
        return make_train_step(self, tx, batch_size, mesh, ema_decay)

    def make_chunk(self, tx, batch_size: int, n_steps: int, mesh=None, *, seed_axis: bool = False,
                   data_axis: int | None = None, ema_decay: float = 0.0):
        return scan_steps(self.make_step(tx, batch_size, mesh, ema_decay), n_steps, seed_axis, data_axis)


def make_train_chunk(agent: Agent, tx, batch_size: int, n_steps: int, mesh=None, *, seed_axis: bool = False,
                     data_axis: int | None = None, ema_decay: float = 0.0):
    """Jitted ``chunk(state, data) -> (state, losses [n_steps])`` (a critic agent's: ``(losses, {name: [n_steps]})``,
    its losses by name beside the total): ``n_steps`` train steps in one ``lax.scan`` (the agent's
    ``make_chunk``; data parallel over ``mesh`` when given: pass ``state`` and ``data`` replicated on it).

    With ``seed_axis`` the state has a leading seed axis (:func:`init_seed_states`) and every step is
    ``vmap``-ed over it: S independent models train in one program, ``losses [n_steps, S]``. ``data_axis``
    0 gives each seed its own sampler data (stacked ``[S, ...]``), ``None`` shares one."""
    return agent.make_chunk(tx, batch_size, n_steps, mesh, seed_axis=seed_axis, data_axis=data_axis,
                            ema_decay=ema_decay)


def init_seed_states(agent: Agent, tx, seeds, ema: bool = False) -> TrainState:
    """One :func:`init_state` per seed, stacked on a leading seed axis ``[S, ...]`` (``vmap`` over the keys, so
    seed s starts exactly where a single-seed run with ``--seed s`` does)."""
    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    return jax.jit(jax.vmap(lambda k: init_state(agent, tx, k, ema)))(keys)


def piece_steps(n: int, whole: bool) -> int:
    """Steps per dispatch within a chunk of ``n``: about a tenth of it, a divisor (one program per chunk length), so
    the progress bar moves within a chunk; the whole chunk where it is not a scan of steps (AWR's iteration)."""
    return n if whole else max(d for d in range(1, max(n // 10, 1) + 1) if n % d == 0)


def merge_losses(pieces: list) -> tuple:
    """The pieces' losses ``[m, S]`` (or ``(losses, {name: [m, S]})``) joined: ``(losses [n, S], parts)``."""
    if not isinstance(pieces[0], tuple):
        return jnp.concatenate(pieces), {}
    return (jnp.concatenate([p[0] for p in pieces]),
            {k: jnp.concatenate([p[1][k] for p in pieces]) for k in pieces[0][1]})
