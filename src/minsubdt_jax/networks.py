"""Networks shared by the SAC behaviour policies (:mod:`minsubdt_jax.behavior`) and the agents
(:mod:`minsubdt_jax.agents`): the ReLU MLP torso."""

from __future__ import annotations

from typing import Any, Sequence

import flax.linen as nn


class MLP(nn.Module):
    """ReLU layers of widths ``hidden``; ``dtype``: the matmuls' dtype (bfloat16 for --precision bf16), parameters
    float32."""

    hidden: Sequence[int]
    dtype: Any = None

    @nn.compact
    def __call__(self, x):
        for h in self.hidden:
            x = nn.relu(nn.Dense(h, dtype=self.dtype)(x))
        return x
