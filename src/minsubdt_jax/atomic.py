"""The one atomic write of the package: every file it writes (a run's JSON, a recorded dataset, a behaviour snapshot,
an experiment's result) is written to a temporary file beside it and renamed into place, so a reader, a crash or a
second writer never sees half of it, and a failed write leaves nothing behind. The file gets the mode the umask
gives a new file (``mkstemp``'s own is 0600)."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager


@contextmanager
def atomic_path(path, suffix: str = ".tmp"):
    """Yields a temporary path beside ``path`` (``<name>.<random><suffix>``, unique per writer) to write to; on
    success it is renamed onto ``path``, on any exception removed. A killed writer's leftover matches
    ``<name>.*<suffix>`` (recordings clean theirs up: :func:`minsubdt_jax.data.named._remove_orphans`)."""
    path = os.fspath(path)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), prefix=os.path.basename(path) + ".",
                               suffix=suffix)
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        os.close(fd)
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


@contextmanager
def atomic_open(path, mode: str = "w"):
    """``open(path, mode)`` for writing, atomically (:func:`atomic_path`): the file appears whole, or not at all."""
    with atomic_path(path) as tmp, open(tmp, mode) as f:
        yield f


def save_figure(fig, path, **kwargs) -> None:
    """``fig.savefig(path, **kwargs)`` atomically (:func:`atomic_path`), in the format of ``path``'s extension."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=os.path.splitext(os.fspath(path))[1][1:] or "png", **kwargs)


def write_atomic(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write(text)


def current_umask() -> int:
    """The process's umask, read from /proc (Linux) so that no other thread ever sees it changed; elsewhere set
    and restored at once."""
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1], 8) for line in f if line.startswith("Umask:"))
    except (OSError, StopIteration, ValueError, IndexError):
        mask = os.umask(0)
        os.umask(mask)
        return mask
