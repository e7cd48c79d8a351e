"""experiments/param_walk.py (issue 75): a walk counted by hand on a three-file package, and the training run's own
walk held at what the refactor left (a change that sends ``cfg`` into more files shows here)."""

import os
import sys


sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "experiments"))
import param_walk  # noqa: E402

FILES = {
    "__init__.py": "",
    "a.py": "from .b import g\nfrom . import c\n\n\ndef start(cfg):\n    run = g(cfg)\n    c.h(run)\n    g(cfg)\n",
    "b.py": "def g(cfg):\n    return k(cfg.steps)\n\n\ndef k(n):\n    return n\n",
    "c.py": "from .b import g\n\n\ndef h(run):\n    cfg = run.cfg\n    g(cfg)\n    m(run)\n\n\n"
            "def m(run):\n    return run.other\n",
}


def test_walk_counted_by_hand(tmp_path):
    (tmp_path / "pkg").mkdir()
    for name, text in FILES.items():
        (tmp_path / "pkg" / name).write_text(text)
    counts, events = param_walk.walk(str(tmp_path), "pkg.a:start:cfg")
    entered = [f"{m}.{f}" for kind, m, f in events if kind == "enter"]
    # g(cfg.steps) hands on a part (k not entered); m(run) neither reads run.cfg nor hands run on (not entered)
    assert entered == ["pkg.a.start", "pkg.b.g", "pkg.c.h", "pkg.b.g", "pkg.b.g"]
    # back from b to a, from b to c, from c to a, from b to a; b opened again from c and from a
    assert counts == {"rooms": 3, "entries": 5, "climbs": 4, "revisits": 2}
    assert param_walk.main(["pkg.a:nothing:cfg", "--src", str(tmp_path)]) == 2


def test_training_walk_stays_a_descent():
    counts, _ = param_walk.walk(os.path.join(os.path.dirname(__file__), "..", "src"), "minsubdt_jax.train:train:cfg")
    # 0caf97e (before issue 75): 22 rooms, 13 climbs, 5 revisits
    assert counts["climbs"] <= 11 and counts["revisits"] <= 5, counts
