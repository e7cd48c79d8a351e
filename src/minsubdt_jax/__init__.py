"""minsubdt_jax: the Minimally Subdominant Decision Transformer as a functional JAX/Flax library.

Data flows one way: dataset (``data``) -> cost features (``costs``) -> min-subdominance and surrogate
returns (``subdominance``) -> DT training (``model``, ``train``) -> batched MJX evaluation (``evaluate``).
"""

from .subdominance import (
    MinSubdominance,
    min_subdominance,
    pairwise_subdominance,
    returns_to_go,
    subdominance,
    surrogate_rewards,
)

__version__ = "0.1.0"
__all__ = ["MinSubdominance", "min_subdominance", "pairwise_subdominance", "returns_to_go", "subdominance",
           "surrogate_rewards"]
