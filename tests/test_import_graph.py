"""The house's imports: no circle, and no arrow from a lower layer to a higher one.

Every import counts, at module level or inside a function: a circle hidden in a
function-level import still ties two modules into one. A module loaded by name
counts too: the kinds the ``cellsim.modules`` entry points name (loaded by
``cellsim.registry``) and any ``"package.module:attribute"`` string in the source.
This walks the source (ast) and pyproject.toml, so it needs nothing imported, and
names the modules of any circle or upward arrow it finds.

The layers, lowest first (docs/architecture.md draws them):

0. foundation: the condition language, the typed YAML, channels and their codec,
   the link rule, the black box file, what a module kind is, the wire protocols of
   other makers' devices (``cellsim.ur``: RTDE); nothing of the cell;
1. model: the scenario, the registry, the systems' base classes, the recorder, and
   the APIs a kind builds on (its abstraction's, its cues');
2. kinds: ``cellsim.kinds.*``, and a plug-in's;
3. assembly: the cell's diagram and the systems it may hold (network I/O, Meshcat),
   the simulation loop, provenance;
4. applications: check, campaign, falsify, verify, replay, Foxglove, the bridge,
   the dashboard, the kinds' docs;
5. the front ends: the public Python API (``cellsim.api``, re-exported by the package ``cellsim``) and the
   command line (``cellsim.cli`` and every ``__main__``), which uses it.

A module may import its own layer and those below. A string-named load (the
registry loading a kind) is how a lower layer reaches a higher one without
depending on it: it counts for circles, not for layers.
"""

from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("cellsim",)

LAYERS = {
    0: ("cellsim.version", "cellsim.hazards", "cellsim.numbers", "cellsim.vocabulary", "cellsim.atomic", "cellsim.config", "cellsim.floorplan",
        "cellsim.kinematics", "cellsim.logic", "cellsim.link", "cellsim.channels", "cellsim.codec", "cellsim.blackbox",
        "cellsim.kind", "cellsim.live.keys", "cellsim.live.pki", "cellsim.ur"),
    1: ("cellsim.systems", "cellsim.registry", "cellsim.scenario", "cellsim.entity", "cellsim.cell_io",
        "cellsim.physical", "cellsim.recorder", "cellsim.verify.model", "cellsim.verify.prism", "cellsim.verify.order",
        "cellsim.verify.expressions", "cellsim.verify.risk", "cellsim.verify.clearance", "cellsim.visual.cues", "cellsim.body",
        "cellsim.proximity"),
    2: ("cellsim.kinds",),
    3: ("cellsim.diagrams", "cellsim.simulation", "cellsim.provenance", "cellsim.live", "cellsim.visual.live",
        "cellsim.visual.scene"),
    4: ("cellsim.validation", "cellsim.campaign", "cellsim.verify", "cellsim.visual", "cellsim.foxglove",
        "cellsim.bridges", "cellsim.dashboard", "cellsim.kinds_doc"),
    5: ("cellsim", "cellsim.api", "cellsim.cli", "cellsim.__main__"),
}
"""Layer -> the modules and packages in it; a module is in the layer of its longest listed prefix."""
LOADED_BY_NAME = re.compile(r"^(cellsim(?:\.\w+)+):\w+$")


def _modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _resolver(modules: dict[str, Path]):
    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    return resolve


def _absolute(module: str, path: Path, node: ast.ImportFrom) -> str:
    """The absolute name an ``ImportFrom`` names, relative ones (``from . import x``) included."""
    if node.level == 0:
        return node.module or ""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for _ in range(node.level - 1):
        package = package.rpartition(".")[0]
    return f"{package}.{node.module}" if node.module else package


def import_graph() -> dict[str, set[str]]:
    """Module -> the package modules it imports (a name imported from a module counts as that module)."""
    modules = _modules()
    resolve = _resolver(modules)
    graph = {name: set() for name in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [resolve(alias.name) for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _absolute(name, path, node)
                targets = [resolve(f"{base}.{alias.name}") for alias in node.names]
            else:
                continue
            graph[name].update(t for t in targets if t and t != name)
    return graph


def loads_by_name() -> dict[str, set[str]]:
    """Module -> the package modules it loads by name: the registry the kinds the entry points name, any
    module the modules whose source holds a ``"package.module:attribute"`` string."""
    modules = _modules()
    resolve = _resolver(modules)
    graph: dict[str, set[str]] = {name: set() for name in modules}
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    for group, entries in project.get("entry-points", {}).items():
        loader = "cellsim.registry" if group == "cellsim.modules" else None
        for value in entries.values():
            target = resolve(value.partition(":")[0])
            if loader and target:
                graph[loader].add(target)
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                found = LOADED_BY_NAME.match(node.value)
                target = resolve(found[1]) if found else None
                if target and target != name:
                    graph[name].add(target)
    return graph


def layer_of(module: str) -> int:
    if module.endswith(".__main__"):
        return 5
    best = max((prefix for prefixes in LAYERS.values() for prefix in prefixes
                if module == prefix or module.startswith(prefix + ".")), key=len, default=None)
    assert best is not None, f"{module} is in no layer: add it to LAYERS"
    return next(layer for layer, prefixes in LAYERS.items() if best in prefixes)


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_the_packages_import_no_circle_loads_by_name_included():
    graph = import_graph()
    assert len(graph) > 50 and "cellsim.diagrams.cell" in graph["cellsim.simulation"]  # it read the real packages
    by_name = loads_by_name()
    assert "cellsim.kinds.robot.kind" in by_name["cellsim.registry"]  # it read the entry points
    for module, targets in by_name.items():
        graph[module] |= targets
    assert circles(graph) == [], "import circles (each line one circle): " + "; ".join(
        " <-> ".join(c) for c in circles(graph))


def test_no_module_imports_a_higher_layer():
    upward = sorted(f"{module} (layer {layer_of(module)}) -> {target} (layer {layer_of(target)})"
                    for module, targets in import_graph().items() for target in targets
                    if layer_of(target) > layer_of(module))
    assert upward == [], "imports of a higher layer:\n" + "\n".join(upward)


def test_the_walk_resolves_relative_imports():
    tree = ast.parse("from . import b\nfrom .c import d\nfrom .. import e")
    found = [_absolute("pkg.sub.a", Path("a.py"), node) for node in tree.body]
    assert found == ["pkg.sub", "pkg.sub.c", "pkg"]
    assert _absolute("pkg.sub", Path("__init__.py"), tree.body[0]) == "pkg.sub"


def test_the_walk_finds_a_circle_hidden_in_a_function():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert circles(graph) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_the_command_line_imports_nothing_heavy_before_its_signal_handlers():
    """An audit found Ctrl-C in the first 0.6 s of a command a traceback from numpy, and SIGTERM then killing it (exit
    143, not 130): ``import cellsim`` loaded the API (numpy, the scenario's schema) to read its public names, before
    any command's handlers existed. The names are listed apart now; the API loads once the handlers are in place."""
    import subprocess
    import sys

    probe = "import sys, cellsim.cli; print(sorted(m for m in ('numpy', 'cellsim.api', 'pydrake') if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stdout + done.stderr
