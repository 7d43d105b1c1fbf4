"""The floor plan holds: no import circle, no private name taken across modules, a small root.

Read from the source with ``ast`` (nothing is imported), over the three packages psrig installs.
Every import counts, also one inside a function (a circle made lazy is still a circle).
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "rig", "calibration")
#: docs/design.md: the pipeline root is the ground floor (and the top floor's few modules)
MAX_ROOT_MODULES = 20


def _modules():
    """{dotted module name: path} of every .py file of the packages."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found[name] = path
    return found


def _resolve(module, path, node):
    """The absolute module a ``from ... import`` names."""
    if not node.level:
        return node.module
    base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    base = base[:len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(modules):
    """Yield (importer, imported module, names taken) for every import in the packages."""
    for module, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    yield module, alias.name, ()
            elif isinstance(node, ast.ImportFrom):
                yield module, _resolve(module, path, node), tuple(a.name for a in node.names)


def _graph(modules):
    graph = {name: set() for name in modules}
    for importer, target, names in _imports(modules):
        for name in names or ("",):
            sub = f"{target}.{name}"
            hit = sub if sub in modules else target if target in modules else None
            if hit and hit != importer:
                graph[importer].add(hit)
    return graph


def _circles(graph):
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return out


@pytest.fixture(scope="module")
def modules():
    return _modules()


def test_no_import_circle(modules):
    assert _circles(_graph(modules)) == []


def test_no_module_takes_another_modules_private_name(modules):
    taken = [f"{importer} takes {name} from {target}" for importer, target, names in _imports(modules)
             for name in names if name.startswith("_") and not name.startswith("__") and target != importer]
    assert taken == []


def test_the_pipeline_root_stays_small(modules):
    root = [name for name, path in modules.items() if path.parent == ROOT / "pipeline"]
    assert len(root) <= MAX_ROOT_MODULES, sorted(root)


def test_the_checks_can_fail():
    """The checker finds a circle and a private import in a made-up graph."""
    assert _circles({"a": {"b"}, "b": {"a"}, "c": set()}) == [["a", "b"]]
    tree = ast.parse("from .engine import _known")
    node = tree.body[0]
    assert _resolve("pipeline.photometric.stage", Path("stage.py"), node) == "pipeline.photometric.engine"
    assert _resolve("pipeline.photometric", Path("__init__.py"), node) == "pipeline.photometric.engine"


def _package(module):
    """The package a module belongs to, as the floor plan counts them: each subpackage of
    pipeline, pipeline's own top floor (its root modules), its face (pipeline/__init__.py) and
    entry point (__main__), and rig and calibration whole."""
    parts = module.split(".")
    if parts[0] != "pipeline":
        return parts[0]
    if len(parts) == 1:
        return "pipeline (face)"
    if parts[1] == "__main__":   # python -m pipeline: the command line's entry point
        return "pipeline (entry point)"
    sub = ROOT / "pipeline" / parts[1]
    return f"pipeline.{parts[1]}" if sub.is_dir() else "pipeline (top floor)"


def test_no_import_circle_between_packages(modules):
    graph = {}
    for importer, targets in _graph(modules).items():
        edges = graph.setdefault(_package(importer), set())
        edges.update(_package(t) for t in targets if _package(t) != _package(importer))
    assert _circles(graph) == []
