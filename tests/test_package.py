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


def _internal_imports() -> dict[str, set[str]]:
    """module -> the package modules it imports (read from the source with ast, nothing executed)."""
    import ast
    import os

    root = os.path.dirname(minsubdt_jax.__file__)
    graph = {}
    for dirpath, _, files in os.walk(root):
        for fn in files:
            if not fn.endswith(".py"):
                continue
            rel = os.path.relpath(os.path.join(dirpath, fn), root)[:-3].replace(os.sep, ".")
            name = "minsubdt_jax" + ("" if rel == "__init__" else "." + rel.removesuffix(".__init__"))
            package = name if fn == "__init__.py" else name.rpartition(".")[0]
            deps = set()
            for node in ast.walk(ast.parse(open(os.path.join(dirpath, fn)).read())):
                if isinstance(node, ast.ImportFrom):
                    base = package
                    for _ in range(max(node.level - 1, 0)):
                        base = base.rpartition(".")[0]
                    mod = (base + ("." + node.module if node.module else "")) if node.level else (node.module or "")
                    deps |= {mod} | {f"{mod}.{a.name}" for a in node.names}
                elif isinstance(node, ast.Import):
                    deps |= {a.name for a in node.names}
            graph[name] = deps
    return {m: {d for d in deps if d in graph and d != m} for m, deps in graph.items()}


def test_imports_have_no_cycle_and_only_the_top_imports_agents():
    """Data flows one way (dataset -> costs -> min-subdominance -> returns -> agents -> run): the package's
    import graph has no cycle (package __init__ files re-export, so they are skipped as edges into them)."""
    graph = _internal_imports()
    inits = {m for m in graph if m == "minsubdt_jax" or any(m == p for p in ("minsubdt_jax.data", "minsubdt_jax.agents",
                                                                        "minsubdt_jax.behavior"))}
    edges = {m: {d for d in deps if d not in inits} for m, deps in graph.items() if m not in inits}
    state = {}

    def visit(m, path):
        if state.get(m) == "done":
            return
        assert state.get(m) != "active", "import cycle: " + " -> ".join(path + [m])
        state[m] = "active"
        for d in edges.get(m, ()):
            visit(d, path + [m])
        state[m] = "done"

    for m in edges:
        visit(m, [])
    assert "minsubdt_jax.references" in edges["minsubdt_jax.scoring"]
    # below the agents nothing imports them (only the run layer: the loop, its program's models, a run evaluated
    # again at a target of one's choosing); recording a
    # dataset does not load the SAC trainer
    users = {m for m, deps in graph.items() if any(d.startswith("minsubdt_jax.agents") for d in deps)}
    assert {u for u in users if not u.startswith("minsubdt_jax.agents")} == {"minsubdt_jax.train",
                                                                            "minsubdt_jax.program",
                                                                            "minsubdt_jax.evaluate",
                                                                            "minsubdt_jax.runsetup",
                                                                            "minsubdt_jax.runresults"}
    assert not any(d.startswith("minsubdt_jax.behavior.train") for d in graph["minsubdt_jax.data.named"])


def test_the_agents_and_their_losses_load_without_the_physics_stack():
    """Issue 57: records and samplers apart from dataset generation. Every agent (and its losses, which read
    ``Transitions`` or ``Batch``) imports without loading the envs, MuJoCo, brax or the SAC behaviour code; the
    data package's I/O and recording load on first use."""
    code = ("import sys, pkgutil, importlib, minsubdt_jax.agents as a\n"
            "for m in pkgutil.walk_packages(a.__path__, 'minsubdt_jax.agents.'): importlib.import_module(m.name)\n"
            "heavy = [n for n in ('minsubdt_jax.envs.rules', 'minsubdt_jax.envs.mjx_backend', "
            "'minsubdt_jax.envs.c_backend', 'mujoco', 'brax', 'minsubdt_jax.behavior', "
            "'minsubdt_jax.data.named', 'minsubdt_jax.data.d4rl') if n in sys.modules]\n"
            "from minsubdt_jax.data import resolve_dataset, save_d4rl\n"
            "print(heavy, 'minsubdt_jax.data.named' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["[]", "True"], out


def _layers() -> dict[str, tuple[int, str]]:
    """``docs/ARCHITECTURE.md``'s layer table, bottom up: each module named at the top level of a row's *modules*
    column (outside parentheses) -> (row index, layer name)."""
    import os
    import re

    with open(os.path.join(os.path.dirname(__file__), "..", "docs", "ARCHITECTURE.md")) as f:
        table = f.read().split("## Layers, bottom up")[1].split("\n\n")[1].splitlines()[2:]
    layer = {}
    for i, row in enumerate(table):
        name, modules = [c.strip() for c in row.strip("|").split("|")][:2]
        depth, top = 0, ""
        for ch in modules:
            depth += (ch == "(") - (ch == ")")
            top += ch if depth == 0 and ch not in "()" else ""
        for m in re.findall(r"`([^`]+)`", top):
            layer["minsubdt_jax." + m.strip("/").replace("/", ".")] = (i, name)
    return layer


def test_the_architecture_layer_table_matches_the_imports():
    """Issue 57: every module is in a row of docs/ARCHITECTURE.md's layer table (a package's row holds its modules),
    and no module imports one of a row above its own."""
    layer, graph = _layers(), _internal_imports()

    def row(m):
        parts = m.split(".")
        return next((layer[".".join(parts[:k])] for k in range(len(parts), 1, -1) if ".".join(parts[:k]) in layer),
                    None)

    assert [m for m in graph if m != "minsubdt_jax" and row(m) is None] == []
    upward = [f"{m} ({row(m)[1]}) imports {d} ({row(d)[1]})" for m, deps in graph.items() if m != "minsubdt_jax"
              for d in deps if d != "minsubdt_jax" and row(d)[0] > row(m)[0]]
    assert upward == []


def test_every_name_the_scripts_import_from_the_package_exists():
    """``experiments/`` and ``benchmarks/`` import the package's names inside functions, where nothing else runs
    them: ``curves.py snapshot`` imported ``platform`` from ``train`` after it had moved to ``runresults`` and failed
    only when a curve was to be saved. Every ``from minsubdt_jax... import name`` in those scripts must resolve."""
    import ast
    import importlib
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1]
    missing = []
    for path in sorted([*root.glob("experiments/*.py"), *root.glob("benchmarks/*.py")]):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("minsubdt_jax"):
                module = importlib.import_module(node.module)
                missing += [f"{path.name}: {node.module}.{a.name}" for a in node.names
                            if not hasattr(module, a.name) and importlib.util.find_spec(
                                f"{node.module}.{a.name}") is None]
    assert not missing, missing


def test_no_function_in_the_package_takes_more_than_8_positional_or_12_parameters():
    """Hand-offs between stages are records (issue 75): no function of ``src/`` takes more than 8 positional
    parameters or 12 in all (``self`` and ``cls`` not counted)."""
    import ast
    import pathlib

    root = pathlib.Path(minsubdt_jax.__file__).parent
    over = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = node.args
                own = int(bool(a.args) and a.args[0].arg in ("self", "cls"))
                pos = len(a.posonlyargs) + len(a.args) - own
                total = pos + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
                if pos > 8 or total > 12:
                    over.append(f"{path.relative_to(root)}:{node.lineno} {node.name} ({pos} positional, {total})")
    assert not over, over


def test_the_experiment_scripts_import_each_other_without_a_circle():
    """experiments/ imports its siblings one way (issue 75: front.py and front_report.py imported each other),
    counting imports inside functions too."""
    import ast
    import pathlib

    folder = pathlib.Path(__file__).resolve().parent.parent / "experiments"
    names = {p.stem for p in folder.glob("*.py")}
    graph = {}
    for p in folder.glob("*.py"):
        deps = set()
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Import):
                deps |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                deps.add(node.module.split(".")[0])
        graph[p.stem] = sorted((deps & names) - {p.stem})
    state = {}

    def visit(n, path):
        if state.get(n) == "done":
            return
        assert state.get(n) != "open", f"import circle: {' -> '.join(path + [n])}"
        state[n] = "open"
        for d in graph[n]:
            visit(d, path + [n])
        state[n] = "done"

    for n in sorted(graph):
        visit(n, [])
    assert "front_report" in graph["front"] and "front" not in graph["front_report"]
