"""minsubdt_jax: the Minimally Subdominant Decision Transformer as a functional JAX/Flax library.

Data flows one way: dataset (``data``) -> cost features (``costs``) -> min-subdominance and surrogate
returns (``subdominance``) -> DT training (``model``, ``train``) -> batched MJX evaluation (``evaluate``).
"""

# No public name may hide a submodule: ``minsubdt_jax.subdominance`` is the module (its eq. 1 function is
# ``minsubdt_jax.subdominance.subdominance``); tests/test_package.py walks the package to keep it so.
from .subdominance import MinSubdominance, min_subdominance, pairwise_subdominance, returns_to_go, surrogate_rewards

__version__ = "0.1.0"
__all__ = ["MinSubdominance", "min_subdominance", "pairwise_subdominance", "returns_to_go", "surrogate_rewards"]
