"""An MLP policy: normalised state -> action in [-1, 1] (the SAC networks' torso, a tanh head)."""

from __future__ import annotations

import flax.linen as nn
import jax.numpy as jnp

from ...networks import MLP


class MLPPolicy(nn.Module):
    """``states [..., obs] -> actions [..., act]``: ``layers`` ReLU layers of ``hidden`` units, tanh head."""

    act_dim: int
    hidden: int = 256
    layers: int = 2

    @nn.compact
    def __call__(self, states):
        return jnp.tanh(nn.Dense(self.act_dim)(MLP((self.hidden,) * self.layers)(states)))
