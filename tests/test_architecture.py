"""The house's rules (docs/architecture.md, "Layers"), checked on the source with ``ast``:

1. direction between the top-level packages: checks/ imports nothing of ours, tracker/ and
   robot_models/ only checks/, policies/ may import robot_models, tracker and checks, harness/ imports all;
2. direction between harness's layers (the table ``HARNESS_LAYERS``);
3. no module imports a leading-underscore module or name of another package (a top-level package,
   or one of harness's layers);
4. no import cycle between modules (imports inside functions count: they are the same dependency);
5. inference code in tracker/ never imports torch.

Each failure names the file and the import."""

from __future__ import annotations

import ast
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("checks", "tracker", "robot_models", "policies", "harness")
ALLOWED = {
    "checks": {"checks"},
    "tracker": {"tracker", "checks"},
    "robot_models": {"robot_models", "checks"},
    "policies": {"policies", "robot_models", "tracker", "checks"},
    "harness": set(OURS),
}
#: harness's layers, bottom to top, and which other layers each may import (docs/architecture.md).
HARNESS_LAYERS = {
    "common": set(),
    "logs": {"common"},
    "sim": {"common"},
    "link": {"sim", "logs", "common"},
    "live": {"sim", "logs", "common"},
    "calib": {"sim", "logs", "common"},
    "experiments": {"live", "link", "sim", "logs", "common"},
    "label": {"experiments", "logs", "common"},
    "cli": {"label", "experiments", "calib", "live", "link", "sim", "logs", "common"},
}


@dataclass(frozen=True)
class Import:
    line: int
    module: str  # the module imported (a submodule named in ``from P import mod`` is that module)
    name: str | None  # the name taken from it, for ``from M import name``


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@cache
def modules() -> dict[str, Path]:
    return {module_name(p): p for top in OURS for p in sorted((ROOT / top).rglob("*.py"))}


@cache
def imports_of(path: Path) -> tuple[Import, ...]:
    """Every import of ours in ``path``, relative ones resolved, wherever it sits in the file."""
    mods = modules()
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [Import(node.lineno, a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for a in node.names:
                sub = f"{target}.{a.name}"
                found.append(Import(node.lineno, sub, None) if sub in mods else Import(node.lineno, target, a.name))
    return tuple(i for i in found if i.module.split(".")[0] in OURS)


def unit_of(module: str) -> str:
    """The package a module belongs to for the rules: a top-level package, or ``harness.<layer>``."""
    parts = module.split(".")
    if parts[0] == "harness" and len(parts) > 1 and parts[1] in HARNESS_LAYERS:
        return f"harness.{parts[1]}"
    return parts[0]


def where(path: Path, imp: Import) -> str:
    what = f"from {imp.module} import {imp.name}" if imp.name else f"import {imp.module}"
    return f"{path.relative_to(ROOT)}:{imp.line}: {what}"


def all_imports():
    for mod, path in modules().items():
        for imp in imports_of(path):
            yield mod, path, imp


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_import_direction(package):
    bad = [f"{where(path, imp)} ({package}/ may import only {sorted(ALLOWED[package])})"
           for mod, path, imp in all_imports()
           if mod.split(".")[0] == package and imp.module.split(".")[0] not in ALLOWED[package]]
    assert not bad, "\n".join(bad)


def test_harness_has_only_known_layers():
    """Every module of harness/ sits in one of the layers (a new folder is added to the table and the docs)."""
    stray = [str(p.relative_to(ROOT)) for m, p in modules().items()
             if m.startswith("harness.") and m.split(".")[1] not in HARNESS_LAYERS]
    assert not stray, f"modules outside harness's layers {sorted(HARNESS_LAYERS)}: {stray}"


@pytest.mark.parametrize("layer", list(HARNESS_LAYERS))
def test_harness_layer_direction(layer):
    bad = []
    for mod, path, imp in all_imports():
        if unit_of(mod) != f"harness.{layer}" or imp.module.split(".")[0] != "harness":
            continue
        target = unit_of(imp.module)
        if target == "harness":
            bad.append(f"{where(path, imp)} (the harness package itself holds no code to import)")
        elif target != mod and target.split(".")[1] not in HARNESS_LAYERS[layer] | {layer}:
            bad.append(f"{where(path, imp)} (harness/{layer} may import only {sorted(HARNESS_LAYERS[layer]) or 'nothing else of harness'})")
    assert not bad, "\n".join(bad)


def private_part(imp: Import) -> str | None:
    """The leading-underscore module or name an import reaches, if any (dunders are not private)."""
    parts = imp.module.split(".") + ([imp.name] if imp.name else [])
    for p in parts:
        if p.startswith("_") and not p.startswith("__"):
            return p
    return None


def test_no_private_imports_across_packages():
    bad = [f"{where(path, imp)} ({private_part(imp)} is private to {unit_of(imp.module)})"
           for mod, path, imp in all_imports()
           if unit_of(mod) != unit_of(imp.module) and private_part(imp)]
    assert not bad, "\n".join(bad)


def import_graph() -> dict[str, dict[str, Import]]:
    mods = modules()
    graph: dict[str, dict[str, Import]] = {m: {} for m in mods}
    for mod, _, imp in all_imports():
        target = imp.module
        while target not in mods and "." in target:  # `import a.b.c` of a name: the nearest module
            target = target.rpartition(".")[0]
        if target in mods and target != mod:
            graph[mod].setdefault(target, imp)
    return graph


def find_cycles(graph: dict[str, dict[str, Import]]) -> list[list[str]]:
    """One cycle per strongly connected component of more than one module (Tarjan, iterative)."""
    index, low, on_stack, stack, comps = {}, {}, set(), [], []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, it = work[-1]
            for nxt in it:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(graph[nxt])))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        m = stack.pop()
                        on_stack.discard(m)
                        comp.append(m)
                        if m == node:
                            break
                    if len(comp) > 1:
                        comps.append(comp)
    cycles = []
    for comp in comps:  # a shortest way back to the start, inside the component
        members, start = set(comp), min(comp)
        prev, frontier = {start: None}, [start]
        while frontier and start not in [n for f in frontier for n in graph[f]]:
            nxt = []
            for f in frontier:
                for n in graph[f]:
                    if n in members and n not in prev:
                        prev[n] = f
                        nxt.append(n)
            frontier = nxt
        last = next(f for f in frontier if start in graph[f])
        path = [last]
        while prev[path[-1]] is not None:
            path.append(prev[path[-1]])
        cycles.append(path[::-1] + [start])
    return cycles


def test_find_cycles_reports_the_path():
    g = {"a": {"b": None}, "b": {"c": None}, "c": {"a": None}, "d": {"a": None}}
    assert find_cycles(g) == [["a", "b", "c", "a"]]
    assert find_cycles({"a": {"b": None}, "b": {}}) == []


def test_no_import_cycles():
    graph, mods = import_graph(), modules()
    msgs = []
    for cycle in find_cycles(graph):
        steps = [f"  {where(mods[a], graph[a][b])}" for a, b in zip(cycle, cycle[1:])]
        msgs.append(" -> ".join(cycle) + "\n" + "\n".join(steps))
    assert not msgs, "import cycles:\n" + "\n".join(msgs)


def test_inference_never_imports_torch():
    bad = []
    for path in sorted((ROOT / "tracker").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            bad += [f"{path.relative_to(ROOT)}:{node.lineno}: import {n}" for n in names if n.split(".")[0] == "torch"]
    assert not bad, "tracker/ must not import torch:\n" + "\n".join(bad)
