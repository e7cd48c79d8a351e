"""The one way the experiments commit a result as it lands (``table1.py --commit``, ``front.py --commit`` and the
lanes of ``queue.sh``): exactly the named paths, if they changed, leaving the rest of the work tree as it is, and
waiting out another git process (a developer's commit beside a lane) that holds the index lock.

    python experiments/gitcommit.py MESSAGE PATH [PATH ...]
"""

from __future__ import annotations

import os
import subprocess
import sys
import time


def commit_results(paths: list[str], message: str) -> bool:
    """``git commit`` exactly ``paths`` with ``message`` in the repository that holds them, if any of them changed;
    whether a commit was made."""
    cwd = os.path.dirname(os.path.abspath(paths[0]))
    rel = [os.path.relpath(os.path.abspath(p), cwd) for p in paths]
    git(["add", "--", *rel], cwd)
    if subprocess.run(["git", "diff", "--cached", "--quiet", "--", *rel], cwd=cwd).returncode == 0:
        return False  # nothing of theirs changed
    git(["commit", "-q", "-m", message, "--", *rel], cwd)
    return True


def git(args: list[str], cwd: str, wait_s: float = 120.0) -> None:
    """``git args`` in ``cwd``; while another git process holds the index lock, waits for it, up to ``wait_s``, then
    raises as git's own error does."""
    deadline = time.monotonic() + wait_s
    while True:
        p = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True)
        if p.returncode == 0:
            return
        if "index.lock" not in p.stderr or time.monotonic() > deadline:
            raise subprocess.CalledProcessError(p.returncode, p.args, p.stdout, p.stderr)
        time.sleep(0.5)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2:
        print("usage: python experiments/gitcommit.py MESSAGE PATH [PATH ...]", file=sys.stderr)
        return 2
    existing = [p for p in argv[1:] if os.path.exists(p)]
    if existing:
        commit_results(existing, argv[0])
    return 0


if __name__ == "__main__":
    sys.exit(main())
