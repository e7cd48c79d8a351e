"""The Decision Transformer family: ``networks`` (the Flax model), ``losses``, ``policy`` (rollouts), ``agent``."""
