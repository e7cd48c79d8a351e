"""Datasets: the trajectory container and the samplers (imported here), and, loaded on first use, D4RL hdf5 I/O
(``d4rl``) and the named datasets recorded in batched physics (``named``). The records and samplers are what agents
and losses need; keeping I/O and recording lazy means importing ``Transitions`` does not load the physics stack."""

import importlib

from .dataset import DatasetError, Trajectories, concatenate, from_flat, from_padded
from .sampler import Batch, SamplerData, Transitions, draw_episodes, sample_batch, sample_transitions, sampler_data

_LAZY = {**dict.fromkeys(("DatasetFile", "load_d4rl", "open_d4rl", "read_infos", "save_d4rl"), "d4rl"),
         **dict.fromkeys(("NAMED_DATASETS", "cache_dir", "generate", "generate_random", "resolve_dataset"), "named")}

__all__ = [
    "Batch", "DatasetError", "DatasetFile", "NAMED_DATASETS", "SamplerData", "Trajectories", "Transitions", "cache_dir",
    "concatenate", "from_flat", "from_padded", "generate", "generate_random", "load_d4rl", "open_d4rl", "read_infos",
    "draw_episodes", "resolve_dataset", "sample_batch", "sample_transitions", "sampler_data", "save_d4rl",
]


def __getattr__(name):
    """The I/O and recording names, imported from their module on first use (PEP 562)."""
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
