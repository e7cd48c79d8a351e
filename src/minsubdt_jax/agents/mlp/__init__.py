"""Behaviour cloning with an MLP policy: ``networks``, ``losses``, ``agent``."""
