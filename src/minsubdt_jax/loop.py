"""The frame of a training loop, shared by the agents' run (:func:`minsubdt_jax.train.train_loop`) and the behaviour
policies' SAC trainer (:func:`minsubdt_jax.behavior.train.train`): chunks from a start step to the last, a progress
bar, each chunk's records before its checkpoint (a resumed run drops the records past its checkpoint and redoes
them), and a Ctrl-C that stops after the current chunk's checkpoint, with the command that resumes."""

from __future__ import annotations

from typing import Callable

from .rundir import InterruptFlag, Interrupted, progress


def chunk_loop(start: int, total: int, chunk: Callable, save: Callable, *, resume: str, verbose: bool = True,
               unit: str = "step") -> int:
    """Run ``chunk(step, bar) -> step`` (one chunk: it trains, moves ``bar`` and writes its records) from ``start``
    until ``total``, with ``save(step, stopping)`` after each (the checkpoint; ``stopping``: Ctrl-C was pressed, so a
    trainer that checkpoints only now and then does it now). The first Ctrl-C stops after the chunk under way and
    its checkpoint (:class:`~minsubdt_jax.rundir.Interrupted`, whose message ends with ``resume``, the command that
    continues); a second stops at once. An error in a chunk leaves the last checkpoint as it was. Returns the last
    step."""
    bar = progress(total=total, initial=start, disable=not verbose, unit=unit)
    stop = InterruptFlag()
    step = start
    try:
        while step < total:
            step = chunk(step, bar)
            save(step, stop.raised)
            if stop.raised and step < total:
                raise Interrupted(f"stopped after the checkpoint at step {step} of {total}; resume with: {resume}")
    finally:
        stop.restore()
    bar.close()
    return step
