"""Implicit Q-learning (Kostrikov, Nair & Levine 2021; ikostrikov/implicit_q_learning): ``losses``, ``agent``."""
