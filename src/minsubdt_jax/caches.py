"""The user cache: recorded datasets and compiled XLA programs, under ``$XDG_CACHE_HOME/minsubdt_jax`` (else
``~/.cache/minsubdt_jax``). Both are regenerable: deleting the folder costs a re-recording and recompiles."""

from __future__ import annotations

import os


def cache_dir() -> str:
    """``$XDG_CACHE_HOME/minsubdt_jax`` or ``~/.cache/minsubdt_jax``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "minsubdt_jax")


def enable_compilation_cache() -> str:
    """Turn on JAX's persistent compilation cache, so a command run again (or a resumed run) loads its compiled
    programs instead of compiling them (tens of seconds for an MJX rollout on a CPU). Uses
    ``$JAX_COMPILATION_CACHE_DIR`` when set, else ``cache_dir()/xla``. Returns the folder."""
    import jax

    path = jax.config.jax_compilation_cache_dir or os.path.join(cache_dir(), "xla")
    jax.config.update("jax_compilation_cache_dir", path)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return path
