"""AWR, advantage-weighted regression (Peng et al. 2019), in the offline version behind D4RL's numbers
(rail-berkeley/d4rl_evaluations ``awr/``): ``losses``, ``agent``."""
