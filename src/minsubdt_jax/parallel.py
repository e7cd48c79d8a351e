"""Scale-out on JAX's own runtime: a 1-D device mesh over every process's devices, the batch split over it,
parameters replicated; ``jax.distributed`` for several processes.

The same jitted train step runs on one device, on N local devices, or on the devices of several processes:
:func:`shard_batch` constrains the sampled batch to be split along its first axis over the mesh axis
``"data"``; parameters, optimiser state and the dataset are replicated (:func:`replicate`). XLA's partitioner
then runs each device's share of the forward and backward pass (the sampling of its rows included) and
all-reduces the gradients. No pmap and no launcher of our own: nothing about the step's code changes with the
device or process count, and its result does not either (within float tolerance; tested on 1 vs 2 forced CPU
devices and on 1 vs 2 processes).

Several processes (one per host, or several on one machine) are started by the user, each with the same
command plus its coordinates (flags or the environment variables ``JAX_COORDINATOR_ADDRESS``,
``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``); :func:`init_distributed` calls ``jax.distributed.initialize``.
Every process loads the (small) dataset itself and its devices gather their own share of each batch from it.
"""

from __future__ import annotations

import os
import zlib

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "data"
ENV_VARS = {"coordinator_address": "JAX_COORDINATOR_ADDRESS", "num_processes": "JAX_NUM_PROCESSES",
            "process_id": "JAX_PROCESS_ID"}


def distributed_settings(coordinator_address: str | None = None, num_processes: int | None = None,
                         process_id: int | None = None) -> tuple[str | None, int, int]:
    """``(coordinator_address, num_processes, process_id)``: each argument, or when ``None`` its environment
    variable (``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``), or one process.

    Raises ValueError on an inconsistent setting (an id out of range, several processes without a coordinator).
    """
    def env(name, cast):
        raw = os.environ.get(ENV_VARS[name])
        if raw is None or raw == "":
            return None
        try:
            return cast(raw)
        except ValueError:
            raise ValueError(f"{ENV_VARS[name]}={raw!r} is not a valid {name.replace('_', ' ')}") from None

    addr = coordinator_address if coordinator_address is not None else env("coordinator_address", str)
    n = num_processes if num_processes is not None else env("num_processes", int)
    pid = process_id if process_id is not None else env("process_id", int)
    n = 1 if n is None else n
    pid = 0 if pid is None else pid
    if n < 1:
        raise ValueError(f"--num-processes must be >= 1, got {n}")
    if not 0 <= pid < n:
        raise ValueError(f"--process-id must be in [0, {n}) for {n} process(es), got {pid}")
    if n > 1 and not addr:
        raise ValueError(f"{n} processes need --coordinator-address host:port (or JAX_COORDINATOR_ADDRESS)")
    if addr and (":" not in addr or not addr.rsplit(":", 1)[1].isdigit()):
        raise ValueError(f"--coordinator-address must be host:port, got {addr!r}")
    return addr, n, pid


def init_distributed(coordinator_address: str | None = None, num_processes: int | None = None,
                     process_id: int | None = None) -> int:
    """Join a multi-process job with ``jax.distributed.initialize`` when more than one process is asked for
    (see :func:`distributed_settings`); a no-op for one process or when already joined. Must run before any
    other JAX computation in the process. Returns the number of processes."""
    addr, n, pid = distributed_settings(coordinator_address, num_processes, process_id)
    if n == 1:
        return 1
    if not jax.distributed.is_initialized():  # before anything else touches a JAX backend
        jax.distributed.initialize(addr, num_processes=n, process_id=pid)
    if jax.process_count() != n or jax.process_index() != pid:
        raise ValueError(f"this process is {jax.process_index()} of {jax.process_count()}, asked for {pid} of {n}")
    return n


def is_main_process() -> bool:
    """True in process 0, the one that writes checkpoints' metadata, logs and results."""
    return jax.process_index() == 0


def make_mesh(num_devices: int = 0, batch_size: int | None = None) -> Mesh:
    """A 1-D mesh over the first ``num_devices`` local devices of every process (0: all of them).

    Raises ValueError if more devices are asked for than a process has, or if ``batch_size`` does not split
    evenly over the mesh.
    """
    local = jax.local_devices()
    n = len(local) if num_devices == 0 else num_devices
    if not 1 <= n <= len(local):
        raise ValueError(f"--devices {num_devices}: this process has {len(local)} local device(s)")
    by_process = [[d for d in jax.devices() if d.process_index == p] for p in range(jax.process_count())]
    devices = [d for ds in by_process for d in ds[:n]]
    if batch_size is not None and batch_size % len(devices):
        raise ValueError(f"--batch-size {batch_size} must be divisible by the number of devices ({len(devices)})")
    return Mesh(np.asarray(devices), (AXIS,))


def available_bytes() -> int | None:
    """The memory a program can take on one local device: its allocator's limit on an accelerator, else the host's
    available memory (``MemAvailable``); None where neither is known."""
    stats = jax.local_devices()[0].memory_stats() or {}
    if "bytes_limit" in stats:
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    try:
        with open("/proc/meminfo") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
    except (OSError, StopIteration, ValueError):
        return None


def replicate(tree, mesh: Mesh):
    """Place every array of ``tree`` whole on every device of ``mesh`` (every process passes the same values)."""
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))


def shard_batch(batch, mesh: Mesh | None, axis: int = 0):
    """Inside a jitted function: split every array of ``batch`` along ``axis`` over ``mesh``
    (a no-op for no mesh or a one-device mesh)."""
    if mesh is None or mesh.size == 1:
        return batch
    spec = PartitionSpec(*([None] * axis), AXIS)
    return jax.lax.with_sharding_constraint(batch, NamedSharding(mesh, spec))


def gather(tree):
    """Every array of ``tree`` whole, as numpy, in every process (an all-gather across processes when the
    arrays are split over several processes' devices)."""
    if jax.process_count() == 1:
        return jax.device_get(tree)
    return multihost_utils.process_allgather(tree, tiled=True)


def assert_same_across_processes(arrays, what: str) -> None:
    """Raise ValueError unless every process holds bit-identical ``arrays`` (a list of host arrays, e.g. the
    dataset): each process's CRC32 of each array is gathered and compared."""
    if jax.process_count() == 1:
        return
    crcs = np.array([zlib.crc32(np.ascontiguousarray(a).tobytes()) & 0x7FFFFFFF for a in arrays], np.int32)
    every = np.asarray(multihost_utils.process_allgather(crcs))  # [processes, len(arrays)]
    if not (every == every[0]).all():
        raise ValueError(f"the processes disagree on {what}: CRC32 per process {every.tolist()}")
