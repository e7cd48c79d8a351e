"""Decision Transformer (Chen et al. 2021) in Flax.

Tokens ``(R_1, s_1, a_1, R_2, s_2, a_2, ...)``: each modality has its own linear embedding, a learned
timestep embedding is added to all three tokens of a step (no positional embedding), then a LayerNorm, a
causal GPT-2 style pre-LN transformer (ReLU MLP, dropout), and a tanh action head read from each state token.
"""

from __future__ import annotations

import flax.linen as nn
import jax.numpy as jnp


class Block(nn.Module):
    """Pre-LN transformer block: causal self-attention and a ReLU MLP, each with a residual."""

    embed_dim: int
    n_heads: int
    dropout: float
    mlp_ratio: int = 4

    @nn.compact
    def __call__(self, x, attn_mask, deterministic: bool):
        h = nn.LayerNorm()(x)
        h = nn.MultiHeadDotProductAttention(num_heads=self.n_heads, dropout_rate=self.dropout,
                                            deterministic=deterministic)(h, h, mask=attn_mask)
        x = x + nn.Dropout(self.dropout)(h, deterministic=deterministic)
        h = nn.LayerNorm()(x)
        h = nn.Dense(self.mlp_ratio * self.embed_dim)(h)
        h = nn.Dense(self.embed_dim)(nn.relu(h))
        return x + nn.Dropout(self.dropout)(h, deterministic=deterministic)


class DecisionTransformer(nn.Module):
    """Predicts ``a_t`` from ``(R_<=t, s_<=t, a_<t)``.

    Call with states ``[B, K, obs]``, actions ``[B, K, act]``, returns_to_go ``[B, K]``, timesteps
    ``[B, K]`` int, mask ``[B, K]`` bool (False on left padding); returns action predictions ``[B, K, act]``
    in ``[-1, 1]``. Padded tokens are never attended to; predictions at padded steps are meaningless.
    """

    act_dim: int
    embed_dim: int = 128
    n_layers: int = 3
    n_heads: int = 1
    dropout: float = 0.1
    max_timestep: int = 1000

    @nn.compact
    def __call__(self, states, actions, returns_to_go, timesteps, mask, deterministic: bool = True):
        B, K = mask.shape
        d = self.embed_dim
        t_emb = nn.Embed(self.max_timestep, d, name="embed_timestep")(jnp.clip(timesteps, 0, self.max_timestep - 1))
        r = nn.Dense(d, name="embed_return")(returns_to_go[..., None]) + t_emb
        s = nn.Dense(d, name="embed_state")(states) + t_emb
        a = nn.Dense(d, name="embed_action")(actions) + t_emb
        x = jnp.stack([r, s, a], axis=2).reshape(B, 3 * K, d)
        x = nn.LayerNorm(name="embed_ln")(x)
        x = nn.Dropout(self.dropout)(x, deterministic=deterministic)
        token_mask = jnp.repeat(mask, 3, axis=1)  # [B, 3K]
        causal = jnp.tril(jnp.ones((3 * K, 3 * K), bool))
        attn_mask = causal[None, None] & token_mask[:, None, None, :]  # [B, 1, 3K, 3K]: no query sees padding
        for i in range(self.n_layers):
            x = Block(d, self.n_heads, self.dropout, name=f"block_{i}")(x, attn_mask, deterministic)
        x = nn.LayerNorm(name="ln_f")(x)
        h_state = x.reshape(B, K, 3, d)[:, :, 1]
        return jnp.tanh(nn.Dense(self.act_dim, name="predict_action")(h_state))
