"""Datasets: trajectory container, D4RL hdf5 I/O, context-window and transition samplers, named MJX datasets."""

from .d4rl import DatasetFile, load_d4rl, open_d4rl, read_infos, save_d4rl
from .dataset import DatasetError, Trajectories, concatenate, from_flat, from_padded
from .named import NAMED_DATASETS, cache_dir, generate, generate_random, resolve_dataset
from .sampler import Batch, SamplerData, Transitions, draw_episodes, sample_batch, sample_transitions, sampler_data

__all__ = [
    "Batch", "DatasetError", "DatasetFile", "NAMED_DATASETS", "SamplerData", "Trajectories", "Transitions", "cache_dir",
    "concatenate", "from_flat", "from_padded", "generate", "generate_random", "load_d4rl", "open_d4rl", "read_infos",
    "draw_episodes", "resolve_dataset", "sample_batch", "sample_transitions", "sampler_data", "save_d4rl",
]
