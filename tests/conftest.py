"""Shared fixtures: one small dataset per session (C MuJoCo, brax dynamics), written as a D4RL file; one persistent
XLA compilation cache per session, shared by the tests and every subprocess they start, so a program the suite
compiles twice (a resumed run, the same smoke model in another test, a CLI subprocess) compiles once. A fresh
machine pays each distinct compile once; nothing outlives the session."""

import atexit
import os
import shutil
import subprocess
import tempfile

import numpy as np
import pytest

# Most of this suite's time is XLA compiling on the CPU, so the tests compile for compile time, not run time:
# LLVM's expensive passes skipped, XLA's classic CPU emitters (the MLIR fusion emitters are the default) and
# LLVM at -O1. The suite on 2 cores (2026-12-06, one run each): 680 s with the first alone, 602 s adding the
# classic emitters (MJX programs compile ~40 % faster, but threefry draws 2-5x slower), 537 s with --dist worksteal
# and one MJX compile fewer (test_physics), 376 s adding -O1 (which undoes the threefry slowdown: a reset draw
# compiles in 0.4 s, 1.6 s with the defaults). Results agree with the default flags to float rounding, not bit for
# bit: a smoke run's losses are identical, its parameters within 7e-5 and its returns within 4e-6
# (experiments/compare_runs.py on two runs of `python -m minsubdt_jax.train --preset smoke --env hopper`, one with
# XLA_FLAGS set to these).
TEST_XLA_FLAGS = ("--xla_cpu_multi_thread_eigen=true --xla_llvm_disable_expensive_passes=true "
                  "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=1")
os.environ.setdefault("XLA_FLAGS", TEST_XLA_FLAGS)
# Set before jax is imported (test modules import it after this file), so jax's config reads them at import.
# The first process to load this file (the pytest-xdist controller, or pytest itself) makes the folder and removes
# it at exit; xdist workers inherit it through the environment.
if "MINSUBDT_TEST_XLA_CACHE" not in os.environ:
    os.environ["MINSUBDT_TEST_XLA_CACHE"] = tempfile.mkdtemp(prefix="minsubdt-test-xla-")
    atexit.register(shutil.rmtree, os.environ["MINSUBDT_TEST_XLA_CACHE"], ignore_errors=True)
os.environ["JAX_COMPILATION_CACHE_DIR"] = os.environ["MINSUBDT_TEST_XLA_CACHE"]
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.3"

ENV = "hopper"  # the cheapest env to compile and step
HORIZON = 60


@pytest.fixture(scope="session")
def small_dataset():
    """32 random-action hopper episodes of at most 60 steps, recorded inside the test run (``auto`` physics: C
    MuJoCo on the CPU, so no physics compile)."""
    from minsubdt_jax.data import generate_random

    return generate_random(ENV, episodes=32, horizon=HORIZON, seed=0)


@pytest.fixture(scope="session")
def small_dataset_path(small_dataset, tmp_path_factory):
    from minsubdt_jax.data import save_d4rl

    path = tmp_path_factory.mktemp("data") / "hopper-small.hdf5"
    save_d4rl(small_dataset, path, env=ENV, dynamics="brax", physics="mujoco")
    return str(path)


@pytest.fixture(scope="session")
def table1():
    """experiments/table1.py, the sweep script (tests/test_table1*.py)."""
    import table1  # experiments/ (pyproject's pythonpath)

    return table1


@pytest.fixture
def git_repo(tmp_path):
    """``tmp_path`` as a git repository with a committer (the sweeps' commits): ``git(*args) -> stdout`` in it."""
    def git(*args):
        return subprocess.run(["git", *args], cwd=tmp_path, check=True, capture_output=True, text=True).stdout

    git("init", "-q")
    git("config", "user.name", "t")
    git("config", "user.email", "t@t")
    return git


@pytest.fixture(scope="session")
def cli_env(tmp_path_factory):
    """Environment for CLI subprocesses: a private dataset cache (the session's XLA cache is inherited)."""
    env = dict(os.environ)
    env["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg"))
    return env


def brute_force_min_subdominance(F, G, beta, alpha_max=np.inf, leave_one_out=False):
    """[N, K] per-feature minimum of eq. 2 by evaluating g at alpha = 0, every breakpoint beta/|d| (d < 0)
    and the cap, in float64: an independent reference for both solvers."""
    F, G = np.asarray(F, np.float64), np.asarray(G, np.float64)
    beta = np.broadcast_to(np.asarray(beta, np.float64), (F.shape[1],))
    caps = np.broadcast_to(np.asarray(alpha_max, np.float64), (F.shape[1],))  # scalar or one per feature
    out = np.zeros(F.shape)
    for i in range(F.shape[0]):
        for k in range(F.shape[1]):
            d = F[i, k] - G[:, k]
            if leave_one_out:
                d = np.delete(d, i)
            cap = caps[k]
            cands = np.array([0.0] + [beta[k] / -x for x in d if x < 0] + ([cap] if np.isfinite(cap) else []))
            cands = np.minimum(cands, cap)
            out[i, k] = min(np.mean(np.maximum(a * d + beta[k], 0.0)) for a in cands)
    return out
