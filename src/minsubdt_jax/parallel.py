"""Data parallelism on JAX's own sharding: a 1-D device mesh, the batch split over it, parameters replicated.

The same jitted train step runs on one device or on N: :func:`shard_batch` constrains the sampled batch to be
split along its first axis over the mesh axis ``"data"``; parameters, optimiser state and the dataset are
replicated (:func:`replicate`). XLA's partitioner then runs each device's share of the forward and backward
pass and all-reduces the gradients. No pmap: nothing about the step's code changes with the device count, and
its result does not either (within float tolerance; tested on 1 vs 2 forced CPU devices).
"""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "data"


def make_mesh(num_devices: int = 0, batch_size: int | None = None) -> Mesh:
    """A 1-D mesh over the first ``num_devices`` local devices (0: all of them).

    Raises ValueError if more devices are asked for than exist, or if ``batch_size`` does not split evenly.
    """
    devices = jax.local_devices()
    n = len(devices) if num_devices == 0 else num_devices
    if not 1 <= n <= len(devices):
        raise ValueError(f"--devices {num_devices}: this process has {len(devices)} local device(s)")
    if batch_size is not None and batch_size % n:
        raise ValueError(f"--batch-size {batch_size} must be divisible by the number of devices ({n})")
    return Mesh(np.asarray(devices[:n]), (AXIS,))


def replicate(tree, mesh: Mesh):
    """Place every array of ``tree`` whole on every device of ``mesh``."""
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))


def shard_batch(batch, mesh: Mesh | None):
    """Inside a jitted function: split every array of ``batch`` along its first axis over ``mesh``
    (a no-op for no mesh or a one-device mesh)."""
    if mesh is None or mesh.size == 1:
        return batch
    return jax.lax.with_sharding_constraint(batch, NamedSharding(mesh, PartitionSpec(AXIS)))
