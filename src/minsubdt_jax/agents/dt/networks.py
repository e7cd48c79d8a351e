"""Decision Transformer (Chen et al. 2021) in Flax.

Tokens ``(R_1, s_1, a_1, R_2, s_2, a_2, ...)``: each modality has its own linear embedding, a learned
timestep embedding is added to all three tokens of a step (no positional embedding), then a LayerNorm, a
causal GPT-2 style pre-LN transformer (ReLU MLP, dropout), and a tanh action head read from each state token.

Initialisation (where flax's defaults and the references differ): the return embedding follows the original DT
(kzl/decision-transformer) and d3rlpy, torch's ``nn.Linear(1, d)``, kernel and bias from U(-1, 1). flax's zero bias
made ``LN(w R + e_t)`` one direction for every R > 0 (LayerNorm is scale-invariant), and the model ignored its
targets (issue 54). The other embeddings keep flax's: lecun-normal kernels and zero biases for the state and action
embeddings (several inputs, so no such collapse), and std 1/sqrt(d) for the timestep embedding, between d3rlpy's 0.02
and the original DT's 1 (with the return fix, the cosine of the tokens of R = 1.2 and 3.3 at one step is 0.92 at
0.02 and at 1/sqrt(d), 0.89 at 1: the return stays readable at any of them). LayerNorm epsilon: flax's 1e-6.

Dropout masks come from :func:`hash_dropout`, a counter-based hash keyed by one threefry draw per call: the
same inverted dropout as ``flax.linen.Dropout``, without drawing threefry bits for every activation, which
is expensive on a CPU (``benchmarks/README.md``).
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp


# The model's revision, recorded in every results.json (``dt_revision``), so results of two revisions are never pooled
# or kept as one sweep's: 1 (until 2026-12-06) drew the return embedding's bias as 0 (flax's default), which left the
# model unable to read its return tokens (issue 54); 2 draws it as torch's nn.Linear(1, d) does.
DT_REVISION = 2


def _fmix32(x):
    """MurmurHash3's 32-bit finaliser: a bijection of uint32 with full avalanche."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x85EBCA6B)
    x = x ^ (x >> 13)
    x = x * jnp.uint32(0xC2B2AE35)
    return x ^ (x >> 16)


def hash_dropout(rng, rate: float, x):
    """Inverted dropout of ``x`` (any shape): each entry is kept with probability ``1 - rate`` (to 2^-32) and
    scaled by ``1 / (1 - rate)``, else zeroed.

    The mask bit of element ``i`` is ``fmix32(fmix32(i ^ k0) + k1) < (1 - rate) 2^32`` with ``(k0, k1)`` two
    threefry words drawn from ``rng``: one key, one mask; different keys, independent-looking masks.
    """
    if rate == 0.0:
        return x
    k0, k1 = jax.random.bits(rng, (2,), jnp.uint32)
    idx = jax.lax.iota(jnp.uint32, x.size).reshape(x.shape)
    keep = 1.0 - rate
    threshold = jnp.uint32(min(round(keep * 2.0 ** 32), 2 ** 32 - 1))
    return jnp.where(_fmix32(_fmix32(idx ^ k0) + k1) < threshold, x / keep, 0.0).astype(x.dtype)


class HashDropout(nn.Module):
    """``flax.linen.Dropout`` with :func:`hash_dropout` masks (rng collection ``"dropout"``)."""

    rate: float

    @nn.compact
    def __call__(self, x, deterministic: bool):
        if deterministic or self.rate == 0.0:
            return x
        return hash_dropout(self.make_rng("dropout"), self.rate, x)


def _attention(query, key, value, *, bias=None, mask=None, dropout_rng=None, dropout_rate=0.0, deterministic=False,
               dtype=None, precision=None, **_):
    """``flax.linen.dot_product_attention`` with :func:`hash_dropout` on the attention weights (flax passes
    everything but the query, key and value by keyword)."""
    w = nn.dot_product_attention_weights(query, key, bias, mask, dtype=dtype, precision=precision)
    if not deterministic and dropout_rate > 0.0:
        w = hash_dropout(dropout_rng, dropout_rate, w)
    return jnp.einsum("...hqk,...khd->...qhd", w, value, precision=precision)


def torch_linear_init(fan_in: int):
    """PyTorch's default ``nn.Linear(fan_in, d)`` initialiser, for a kernel and for a bias alike: U(-1/sqrt(fan_in),
    1/sqrt(fan_in)) (kaiming-uniform with a = sqrt(5) gives the kernel the same bound)."""
    bound = 1.0 / float(fan_in) ** 0.5

    def init(key, shape, dtype=jnp.float32):
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


class Block(nn.Module):
    """Pre-LN transformer block: causal self-attention and a ReLU MLP, each with a residual."""

    embed_dim: int
    n_heads: int
    dropout: float
    mlp_ratio: int = 4
    dtype: Any = None  # computation dtype of the matmuls (bfloat16 for --precision bf16); parameters stay float32

    @nn.compact
    def __call__(self, x, attn_mask, deterministic: bool, last_only: bool = False):
        """``x [B, T, d]`` -> ``[B, T, d]``; with ``last_only`` only the last token's output ``[B, 1, d]``: its
        query attends to every token's keys and values as before, and nothing else is computed for the others.
        The residual stream and the LayerNorms stay float32 when ``dtype`` is set."""
        ln = (lambda: nn.LayerNorm()) if self.dtype is None else (lambda: nn.LayerNorm(dtype=jnp.float32))  # noqa
        h = ln()(x)
        q = h[:, -1:] if last_only else h
        mask = attn_mask[..., -1:, :] if last_only else attn_mask
        h = nn.MultiHeadDotProductAttention(num_heads=self.n_heads, dropout_rate=self.dropout, dtype=self.dtype,
                                            deterministic=deterministic, attention_fn=_attention)(q, h, mask=mask)
        x = (x[:, -1:] if last_only else x) + HashDropout(self.dropout)(h, deterministic=deterministic)
        h = ln()(x)
        h = nn.Dense(self.mlp_ratio * self.embed_dim, dtype=self.dtype)(h)
        h = nn.Dense(self.embed_dim, dtype=self.dtype)(nn.relu(h))
        return x + HashDropout(self.dropout)(h, deterministic=deterministic)


class DecisionTransformer(nn.Module):
    """Predicts ``a_t`` from ``(R_<=t, s_<=t, a_<t)``.

    Call with states ``[B, K, obs]``, actions ``[B, K, act]``, returns_to_go ``[B, K]`` (or ``[B, K, R]``: a
    return per cost metric, embedded by one ``nn.Linear(R, d)``, torch's init at fan-in R), timesteps
    ``[B, K]`` int, mask ``[B, K]`` bool (False on left padding); returns action predictions ``[B, K, act]``
    in ``[-1, 1]``. Padded tokens are never attended to; predictions at padded steps are meaningless.

    ``last_only=True`` (the rollout policy) returns the prediction at the last state ``[B, act]`` alone, and computes
    only what it depends on: the last action token (which no earlier token sees) is dropped, and the last layer,
    the final LayerNorm and the head run for that one token. The same function as ``[:, -1]`` of the full call, to
    float rounding (tested).
    """

    act_dim: int
    embed_dim: int = 128
    n_layers: int = 3
    n_heads: int = 1
    dropout: float = 0.1
    max_timestep: int = 1000
    dtype: Any = None  # matmul dtype (None: float32); parameters, LayerNorms and outputs stay float32

    @nn.compact
    def __call__(self, states, actions, returns_to_go, timesteps, mask, deterministic: bool = True,
                 last_only: bool = False):
        B, K = mask.shape
        d = self.embed_dim
        dt, f32 = self.dtype, (lambda y: y) if self.dtype is None else (lambda y: y.astype(jnp.float32))  # noqa
        t_emb = nn.Embed(self.max_timestep, d, name="embed_timestep")(jnp.clip(timesteps, 0, self.max_timestep - 1))
        # torch's nn.Linear(1, d) init (the original DT's and d3rlpy's), not flax's zero bias: LayerNorm is
        # scale-invariant, so a zero-bias LN(w R + e_t) is nearly one direction for every R > 0 (issue 54)
        rtg = returns_to_go[..., None] if returns_to_go.ndim == mask.ndim else returns_to_go  # [B, K, R], R >= 1
        u = torch_linear_init(rtg.shape[-1])
        r = f32(nn.Dense(d, dtype=dt, kernel_init=u, bias_init=u, name="embed_return")(rtg)) + t_emb
        s = f32(nn.Dense(d, dtype=dt, name="embed_state")(states)) + t_emb
        a = f32(nn.Dense(d, dtype=dt, name="embed_action")(actions)) + t_emb
        x = jnp.stack([r, s, a], axis=2).reshape(B, 3 * K, d)
        x = nn.LayerNorm(name="embed_ln")(x)
        x = HashDropout(self.dropout)(x, deterministic=deterministic)
        token_mask = jnp.repeat(mask, 3, axis=1)  # [B, 3K]
        causal = jnp.tril(jnp.ones((3 * K, 3 * K), bool))
        attn_mask = causal[None, None] & token_mask[:, None, None, :]  # [B, 1, 3K, 3K]: no query sees padding
        if last_only:  # up to the last state token
            x, attn_mask = x[:, :-1], attn_mask[..., :-1, :-1]
        for i in range(self.n_layers):
            last = last_only and i == self.n_layers - 1
            x = Block(d, self.n_heads, self.dropout, dtype=dt, name=f"block_{i}")(x, attn_mask, deterministic, last)
        x = nn.LayerNorm(name="ln_f")(x)
        if last_only:
            return jnp.tanh(f32(nn.Dense(self.act_dim, dtype=dt, name="predict_action")(x[:, -1])))
        h_state = x.reshape(B, K, 3, d)[:, :, 1]
        return jnp.tanh(f32(nn.Dense(self.act_dim, dtype=dt, name="predict_action")(h_state)))
