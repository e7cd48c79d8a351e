"""BEAR, bootstrapping error accumulation reduction (Kumar et al. 2019; the version behind D4RL's numbers,
rail-berkeley/d4rl_evaluations ``bear/``): ``networks`` (its behaviour VAE), ``losses``, ``agent``."""
