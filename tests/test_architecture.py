"""The layout rules of ARCHITECTURE.md, checked on the source tree.

Layers look down only: models -> estimators -> wbc -> scenarios -> application (wbc_hdmm,
benchmarks). Test doubles live in `testkit` (used by tests and benchmarks only). No import
cycles, no production file over 450 lines, no `testing.py` in a production package.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("models", "estimators", "wbc", "scenarios", "wbc_hdmm")  # bottom to top
PRODUCTION = LAYERS[:4]
MAX_LINES = 450
# What each package may import from the project (itself included).
ALLOWED = {
    "models": {"models"},
    "estimators": {"models", "estimators"},
    "wbc": {"models", "estimators", "wbc"},
    "scenarios": {"models", "estimators", "wbc", "scenarios"},
    "wbc_hdmm": {"models", "estimators", "wbc", "scenarios", "wbc_hdmm", "benchmarks"},
    "benchmarks": {"models", "estimators", "wbc", "scenarios", "benchmarks", "testkit"},
    "testkit": {"models", "estimators", "wbc", "testkit"},
}
PROJECT = set(ALLOWED)


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in ALLOWED:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """Project modules imported by the file (every import, or module-level ones only)."""
    tree = ast.parse(path.read_text(), str(path))
    if top_level_only:  # executed at import: module level, under module-level if/try
        stack, nodes = list(tree.body), []
        while stack:
            n = stack.pop()
            nodes.append(n)
            if isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test):
                continue
            if isinstance(n, (ast.If, ast.Try)):
                stack.extend(ast.iter_child_nodes(n))
    else:
        nodes = list(ast.walk(tree))
    names = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return {n for n in names if n.split(".")[0] in PROJECT}


def _resolve(name: str) -> str | None:
    """The project module a dotted import name refers to (longest known prefix)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in MODULES:
            return cand
    return None


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_layers_only_look_down(package):
    bad = []
    for mod, path in MODULES.items():
        if mod.split(".")[0] != package:
            continue
        for name in _imports(path, top_level_only=False):
            if name.split(".")[0] not in ALLOWED[package]:
                bad.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not bad, "imports against the layer order:\n" + "\n".join(sorted(bad))


def test_no_import_cycles():
    graph = {m: set() for m in MODULES}
    for mod, path in MODULES.items():
        for name in _imports(path, top_level_only=True):
            target = _resolve(name)
            if target is not None and target != mod and not mod.startswith(target + "."):
                graph[mod].add(target)
    # Tarjan's strongly connected components.
    index, low, on_stack, stack, cycles = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_production_files_are_short():
    long = [f"{p.relative_to(ROOT)}: {n} lines" for m, p in MODULES.items()
            if m.split(".")[0] in PRODUCTION
            and (n := len(p.read_text().splitlines())) > MAX_LINES]
    assert not long, f"production files over {MAX_LINES} lines: {long}"


def test_no_test_doubles_in_production_packages():
    found = [str(p.relative_to(ROOT)) for m, p in MODULES.items()
             if m.split(".")[0] in PRODUCTION
             and p.stem in ("testing", "synthetic", "fakes", "mocks", "conftest")]
    assert not found, f"test doubles in production packages: {found}"
    users = [m for m, p in MODULES.items() if m.split(".")[0] in PRODUCTION
             and any(n.split(".")[0] == "testkit" for n in _imports(p, False))]
    assert not users, f"production modules importing testkit: {users}"


def test_the_rules_see_a_back_edge(tmp_path):
    """The checker itself: a models module importing wbc is caught."""
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from wbc import make_controller\n")
    assert _imports(f, top_level_only=False) == {"wbc", "wbc.make_controller"}
    assert _imports(f, top_level_only=True) == set()
