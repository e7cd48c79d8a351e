"""What the CLI tests share: the smallest training run's flags, the training CLI called in this process, and a run
directory's latest checkpoint (tests/test_train_cli.py, test_faults.py, test_bad_input.py, test_critics.py)."""

import os

SMOKE = ["--preset", "smoke", "--env", "hopper", "--episode-length", "60"]


def train_main(args, capsys, stream="err"):
    """``python -m minsubdt_jax.train`` in this process (no interpreter start-up): (exit code, its stderr, or
    stdout with stream="out")."""
    from minsubdt_jax.train import main

    code = main(args)
    return code, getattr(capsys.readouterr(), stream)


def checkpoint_params(run_dir):
    """(step, state) of ``run_dir``'s latest checkpoint, restored by orbax."""
    import orbax.checkpoint as ocp

    mngr = ocp.CheckpointManager(os.path.abspath(os.path.join(run_dir, "checkpoints")))
    return mngr.latest_step(), mngr.restore(mngr.latest_step())


def leaves(tree):
    import jax

    return jax.tree.leaves(tree)
