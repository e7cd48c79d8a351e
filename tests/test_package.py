"""The package's shape: every public submodule is what ``import minsubdt_jax.X as m`` and
``from minsubdt_jax import X`` give (no re-exported name hides a module)."""

import importlib
import pkgutil
import subprocess
import sys

import minsubdt_jax


def _public_modules():
    return [m.name for m in pkgutil.walk_packages(minsubdt_jax.__path__, "minsubdt_jax.")
            if not any(part.startswith("_") for part in m.name.split(".")[1:])]


def test_every_public_submodule_is_a_module_under_its_name():
    names = _public_modules()
    assert {"minsubdt_jax.subdominance", "minsubdt_jax.data.named", "minsubdt_jax.behavior.train"} <= set(names)
    for name in names:
        module = importlib.import_module(name)
        parent, _, last = name.rpartition(".")
        # `import a.b.c as m` and `from a.b import c` both read the attribute c of a.b
        assert getattr(importlib.import_module(parent), last) is module, f"{name} is hidden by a name in {parent}"


def test_import_as_gives_the_module_in_a_fresh_interpreter():
    """The same, the way a user writes it, before anything else has imported the submodules."""
    code = ("import types\n"
            "import minsubdt_jax.subdominance as sd\n"
            "from minsubdt_jax import subdominance as sd2\n"
            "import minsubdt_jax.data.named as named\n"
            "assert isinstance(sd, types.ModuleType) and sd is sd2 and callable(sd.subdominance), sd\n"
            "assert isinstance(named, types.ModuleType) and callable(named.generate), named\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
