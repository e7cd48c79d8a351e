"""BRAC-v, behaviour-regularised actor-critic with a value penalty (Wu, Tucker & Nachum 2019; the version behind
D4RL's numbers, rail-berkeley/d4rl_evaluations ``brac/``): ``losses``, ``agent``."""
