"""Behaviour policies for making D4RL-style datasets: a pmap-free, jitted SAC trainer (``behavior.train``),
its networks and losses, and the committed policy snapshots (``behavior.policies``)."""
