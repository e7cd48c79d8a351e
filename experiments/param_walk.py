"""Follow one value through the package as a reader would (issue 75's "parameter walk"): from a function's parameter,
into every function of the package it is passed to, in source order, depth first.

    python experiments/param_walk.py minsubdt_jax.train:train:cfg            # the work tree's src/
    python experiments/param_walk.py minsubdt_jax.train:train:cfg --src /tmp/old/src --path

What counts as the value (read statically, with ``ast``; a heuristic, the same for any two revisions compared):
the parameter itself, a name assigned from it, a copy (``dataclasses.replace(cfg, ...)``) and a record's field named
as the parameter (``run.cfg``); a part of it (``cfg.steps``) is not the value. A call whose argument is one of
these, to a function the package defines
(resolved through its ``from ... import`` lines, ``__init__`` re-exports and module aliases), is entered with the
matching parameters holding the value. Methods of objects (``agent.policy(...)``) and classes are not entered.

What it counts, the path being the sequence of functions the reader opens, and the files they live in:

- ``rooms``: distinct functions entered; ``entries``: every entry (a function entered again is counted but not
  read again);
- ``climbs``: returns from a function in another file than its caller's (the reader goes back up to a file they
  had left);
- ``revisits``: entries into a file the reader had left before (not by a return: a second visit down).

A one-way descent has no revisits and as few climbs as it has files below the start.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import sys


class Package:
    """The modules of a package under ``src``: their syntax trees, top-level functions and imported names."""

    def __init__(self, src: str, package: str):
        self.src, self.package, self.trees = src, package, {}
        root = os.path.join(src, package)
        for dirpath, _, files in os.walk(root):
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(dirpath, f), src)[:-3].replace(os.sep, ".")
                    name = rel[: -len(".__init__")] if rel.endswith(".__init__") else rel
                    with open(os.path.join(dirpath, f)) as fh:
                        self.trees[name] = (ast.parse(fh.read()), f == "__init__.py")

    def functions(self, module: str) -> dict:
        return {n.name: n for n in self.trees[module][0].body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}

    def _absolute(self, module: str, node: ast.ImportFrom) -> str:
        if node.level == 0:
            return node.module or ""
        is_pkg = self.trees[module][1]
        base = module.split(".")[: len(module.split(".")) - node.level + (1 if is_pkg else 0)]
        return ".".join(base + ([node.module] if node.module else []))

    def resolve(self, module: str, name: str, depth: int = 0):
        """(module, function) that ``name`` means in ``module``, or a module name for a module alias, or None."""
        if depth > 10 or module not in self.trees:
            return None
        if name in self.functions(module):
            return module, name
        for node in self.trees[module][0].body:
            if isinstance(node, ast.ImportFrom):
                src = self._absolute(module, node)
                for a in node.names:
                    if (a.asname or a.name) == name:
                        if f"{src}.{a.name}" in self.trees:
                            return f"{src}.{a.name}"
                        return self.resolve(src, a.name, depth + 1)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if (a.asname or a.name) == name and a.name in self.trees:
                        return a.name
        return None


class Walk:
    def __init__(self, pkg: Package, param: str):
        self.pkg, self.param, self.events, self.seen, self.stack = pkg, param, [], set(), []

    def is_value(self, expr, values: set) -> bool:
        """Whether ``expr`` is the walked value whole: a name holding it, ``x.<param>`` (a record's field named as
        the parameter, ``run.cfg``), or ``replace(value, ...)`` (a copy with some fields changed)."""
        if isinstance(expr, ast.Starred):
            expr = expr.value
        if isinstance(expr, ast.Name):
            return expr.id in values
        if isinstance(expr, ast.Attribute):
            return expr.attr == self.param
        f = expr.func if isinstance(expr, ast.Call) else None
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
        return name == "replace" and bool(expr.args) and self.is_value(expr.args[0], values)

    def reads(self, fn, p: str) -> bool:
        """Whether ``fn`` reads the value out of its parameter ``p`` (``p.<param>``) or hands ``p`` on."""
        return any(isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == p
                   and n.attr == self.param or isinstance(n, ast.Call) and any(
                       isinstance(a, ast.Name) and a.id == p for a in _args(n)) for n in ast.walk(fn))

    def callee(self, module: str, func):
        if isinstance(func, ast.Name):
            got = self.pkg.resolve(module, func.id)
        elif isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name):
            mod = self.pkg.resolve(module, func.value.id)
            got = (mod, func.attr) if isinstance(mod, str) and func.attr in self.pkg.functions(mod) else None
        else:
            got = None
        return got if isinstance(got, tuple) else None

    def assign(self, node: ast.Assign, values: set, records: set):
        """A name assigned the value holds it; one assigned what a call given the value (or a record of it) returned
        holds a record of it (``run = plan_run(cfg)``)."""
        names = {n.id for t in node.targets for n in ast.walk(t) if isinstance(n, ast.Name)}
        if self.is_value(node.value, values):
            values |= names
        elif isinstance(node.value, ast.Name) and node.value.id in records or isinstance(node.value, ast.Call) and any(
                self.is_value(a, values) or isinstance(a, ast.Name) and a.id in records for a in _args(node.value)):
            records |= names

    def enter(self, module: str, name: str, values: set, records: set):
        key = (module, name)
        self.events.append(("enter", module, name))
        if key in self.seen or key in self.stack:
            self.events.append(("return", module, name))
            return
        self.seen.add(key)
        self.stack.append(key)
        values, records = set(values), set(records)
        for node in _in_order(self.pkg.functions(module)[name].body):
            if isinstance(node, ast.Assign):
                self.assign(node, values, records)
            got = self.callee(module, node.func) if isinstance(node, ast.Call) else None
            if got:
                fn = self.pkg.functions(got[0])[got[1]]
                v = _bound(fn, node, lambda e: self.is_value(e, values))
                r = {p for p in _bound(fn, node, lambda e: isinstance(e, ast.Name) and e.id in records)
                     if self.reads(fn, p)}
                if v or r:
                    self.enter(*got, v, r)
        self.stack.pop()
        self.events.append(("return", module, name))


def _args(call: ast.Call):
    return list(call.args) + [k.value for k in call.keywords]


def _in_order(body):
    """The nodes of a function body in source order (nested functions and classes left out)."""
    out = []

    def visit(n):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)):
            return
        out.append(n)
        for child in ast.iter_child_nodes(n):
            visit(child)
    for stmt in body:
        visit(stmt)
    return sorted(out, key=lambda n: (getattr(n, "lineno", 0), getattr(n, "col_offset", 0)))


def _bound(fn, call: ast.Call, carries) -> set:
    """The parameters of ``fn`` that ``call`` binds to a value that carries the walked one."""
    names = [a.arg for a in fn.args.posonlyargs + fn.args.args]
    out = {names[i] for i, a in enumerate(call.args) if i < len(names) and carries(a)}
    return out | {k.arg for k in call.keywords if k.arg and carries(k.value)}


def measure(events: list) -> dict:
    """rooms, entries, climbs and revisits of a walk's enter/return events (the module docstring)."""
    files, left, climbs, revisits, entries, rooms = [], set(), 0, 0, 0, set()
    for kind, module, name in events:
        if kind == "enter":
            entries += 1
            rooms.add((module, name))
            if files and module != files[-1]:
                left.add(files[-1])
                revisits += module in left
            files.append(module)
        else:
            files.pop()
            if files and files[-1] != module:
                climbs += 1
                left.add(module)
    return {"rooms": len(rooms), "entries": entries, "climbs": climbs, "revisits": revisits}


def walk(src: str, start: str) -> tuple[dict, list]:
    module, name, param = start.split(":")
    w = Walk(Package(src, module.split(".")[0]), param)
    if name not in w.pkg.functions(module):
        raise ValueError(f"{module} defines no function {name}")
    w.enter(module, name, {param}, set())
    return measure(w.events), w.events


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("start", help="module:function:parameter, e.g. minsubdt_jax.train:train:cfg")
    p.add_argument("--src", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src"))
    p.add_argument("--path", action="store_true", help="also print the functions entered, indented by depth")
    a = p.parse_args(argv)
    try:
        counts, events = walk(a.src, a.start)
    except (ValueError, KeyError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if a.path:
        depth = 0
        for kind, module, name in events:
            if kind == "enter":
                print("  " * depth + f"{module}.{name}")
                depth += 1
            else:
                depth -= 1
    print(json.dumps(counts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
