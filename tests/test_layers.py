"""The package's layers, read from the code's own imports (eager and lazy alike).

Data flows one way: core -> map -> tokens -> model -> generation -> sim -> data -> export -> the applications
(train, evaluate, sweep, fill) -> the ``run`` CLI -> the studio (a web app over ``run``) -> the
``scendiff`` command -> the package's re-exports. A module may import
from its own layer or a lower one, never from a higher one or a sibling application, and no chain
of imports may come back to where it started (docs/architecture.md).
"""
from __future__ import annotations

import ast
import os

import pytest

PKG = "sumo_scendiff"
ROOT = os.path.join(os.path.dirname(__file__), "..", PKG)
LAYERS = [{"core"}, {"map"}, {"tokens"}, {"model"}, {"generation"}, {"sim"}, {"data"}, {"export"},
          {"train", "evaluate", "sweep", "fill"}, {"run"}, {"studio"}, {"console"},
          {"__init__"}]
RANK = {room: k for k, rooms in enumerate(LAYERS) for room in rooms}


def modules() -> dict[str, str]:
    """dotted module name (without the package) -> file."""
    out = {}
    for here, _, files in os.walk(ROOT):
        for f in files:
            if f.endswith(".py"):
                rel = os.path.relpath(os.path.join(here, f), ROOT)[:-3].replace(os.sep, ".")
                out[rel] = os.path.join(here, f)
    return out


def room(mod: str) -> str:
    return mod.split(".")[0]


def imports(mod: str, path: str, known: set[str]) -> set[str]:
    """The package modules ``mod`` imports, anywhere in its file."""
    pkg = mod.split(".")[:-1]   # "a.b" and "a.__init__" both live in package "a"
    found = set()
    for node in ast.walk(ast.parse(open(path).read(), path)):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            elif node.module and node.module.split(".")[0] == PKG:
                target = node.module[len(PKG) + 1:]
            else:
                continue
            names = [f"{target}.{a.name}" if target else a.name for a in node.names]
            hits = [n for n in names if n in known or f"{n}.__init__" in known]
            found |= {n if n in known else f"{n}.__init__" for n in hits}
            if len(hits) < len(names):
                found.add(target if target in known else f"{target}.__init__" if target else "__init__")
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == PKG and a.name != PKG:
                    found.add(a.name[len(PKG) + 1:])
    return {f for f in found if f in known and f != mod}


def graph() -> dict[str, set[str]]:
    mods = modules()
    return {m: imports(m, p, set(mods)) for m, p in mods.items()}


def test_every_module_has_a_layer():
    assert not [m for m in modules() if room(m) not in RANK]


def test_no_import_runs_up_the_layers_or_across_applications():
    wrong = []
    for m, targets in graph().items():
        for t in targets:
            a, b = room(m), room(t)
            if m.endswith("__init__") and m.count(".") == 0:
                continue   # the package's lazy re-exports sit above everything
            if RANK[b] > RANK[a] or (RANK[b] == RANK[a] and a != b):
                wrong.append(f"{m} -> {t}")
    assert not wrong, "imports against the data flow:\n" + "\n".join(sorted(wrong))


def test_no_import_circle():
    g = graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in sorted(g[m]):
            if state.get(t) == 1:
                pytest.fail("import circle: " + " -> ".join(stack[stack.index(t):] + [t]))
            if t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m)


def test_the_checker_sees_an_upward_and_a_circular_import(tmp_path):
    """The reader finds relative, absolute and lazy imports (a checker that finds nothing would pass)."""
    f = tmp_path / "x.py"
    f.write_text("from ..generation.generator import A\n"
                 "def g():\n    from sumo_scendiff.sim import seeding\n    import sumo_scendiff.map.raster\n")
    known = {"generation.generator", "sim.seeding", "sim.__init__", "map.raster", "core.x"}
    assert imports("core.x", str(f), known) == {"generation.generator", "sim.seeding", "map.raster"}
