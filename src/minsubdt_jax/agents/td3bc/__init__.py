"""TD3+BC (Fujimoto & Gu 2021; sfujim/TD3_BC): ``losses``, ``agent``."""
