"""Layering of the ``ifmi`` package: no import cycles, the front-end contract stands alone.

The graph is built from the source with :mod:`ast`, so imports inside
functions (deferred imports) count too: a cycle hidden behind a deferred
import is still a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import ifmi

PACKAGE_DIR = Path(ifmi.__file__).resolve().parent


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_modules(path: Path, modules: set[str]) -> set[str]:
    """``ifmi`` modules that the file at ``path`` imports (anywhere in it)."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[:len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            # "from pkg import mod" imports the module pkg.mod when it is one.
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                       for alias in node.names]
        else:
            continue
        out.update(t for t in targets if t in modules and t != name)
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the ``ifmi`` modules it imports."""
    files = {_module_name(p): p for p in PACKAGE_DIR.rglob("*.py")}
    return {name: _imported_modules(path, set(files)) for name, path in files.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle ``[a, b, ..., a]`` of ``graph``, or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def test_graph_sees_deferred_imports():
    graph = import_graph()
    # ifmi.tracking.methods imports the iFMI front end inside a function only.
    assert "ifmi.spectral.ifmi_front_end" in graph["ifmi.tracking.methods"]
    assert "ifmi.front_end" in graph["ifmi.features"]


def test_cycle_finder_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert find_cycle(graph) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_ifmi_has_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_front_end_contract_imports_nothing_of_ifmi():
    assert import_graph()["ifmi.front_end"] == set()


def test_ifmi_never_imports_omnisim():
    for path in PACKAGE_DIR.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                     else [])
            assert not any(n.split(".")[0] == "omnisim" for n in names), path


# Layers, lowest first: a module may import its own layer and those below, never one above.
# Pure math (no file I/O) sits below ``ifmi.io``; the applications that read and write files
# (pipeline, evaluation of files, experiments) sit above it, and the command line on top.
LAYERS = (
    ("base", ("ifmi.errors", "ifmi.options", "ifmi.frames", "ifmi.front_end", "ifmi.runtime")),
    ("geometry", ("ifmi.geometry",)),
    # calib_fit checks a fitted model over the panorama band, so it sits with the math above geometry.
    ("math", ("ifmi.spectral", "ifmi.backend", "ifmi.features", "ifmi.evaluation.metrics",
              "ifmi.evaluation.dataset_names", "ifmi.geometry.calib_fit")),
    ("tracking", ("ifmi.tracking", "ifmi.config")),
    ("io", ("ifmi.io",)),
    ("application", ("ifmi.pipeline", "ifmi.evaluation", "ifmi.synthetic", "ifmi.testing", "ifmi.api")),
    ("experiments", ("ifmi.experiments",)),
    ("cli", ("ifmi.cli", "ifmi")),
)

# The parts of ifmi that omnisim may use: a shared base, never the estimator.
OMNISIM_ALLOWED = ("ifmi.errors", "ifmi.io", "ifmi.geometry", "ifmi.spectral.panorama", "ifmi.runtime")


def layer_of(module: str) -> int:
    """Index in :data:`LAYERS` of the longest prefix that names ``module``'s layer."""
    best, best_len = None, -1
    for index, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = index, len(prefix)
    if best is None:
        raise KeyError(f"{module} belongs to no layer; add it to LAYERS")
    return best


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """``"a -> b"`` for every import of a module in a higher layer than the importer's."""
    return sorted(f"{a} ({LAYERS[layer_of(a)][0]}) -> {b} ({LAYERS[layer_of(b)][0]})"
                  for a, targets in graph.items() for b in targets if layer_of(b) > layer_of(a))


def test_every_module_has_a_layer():
    for module in import_graph():
        layer_of(module)


def test_layer_check_finds_a_planted_upward_import():
    assert upward_imports({"ifmi.io.config": {"ifmi.pipeline"}}) == [
        "ifmi.io.config (io) -> ifmi.pipeline (application)"]
    assert upward_imports({"ifmi.pipeline": {"ifmi.io.config"}}) == []


def test_no_module_imports_a_higher_layer():
    assert upward_imports(import_graph()) == []


def omnisim_imports_of_ifmi() -> dict[str, set[str]]:
    """omnisim module file name -> the ``ifmi`` modules it imports (anywhere in it)."""
    omnisim_dir = PACKAGE_DIR.parent / "omnisim"
    out = {}
    for path in omnisim_dir.rglob("*.py"):
        names = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names.add(node.module)
        out[path.name] = {n for n in names if n.split(".")[0] == "ifmi"}
    return out


def test_omnisim_imports_the_shared_base_only():
    outside = {f"{name}: {module}" for name, modules in omnisim_imports_of_ifmi().items()
               for module in modules
               if not any(module == p or module.startswith(p + ".") for p in OMNISIM_ALLOWED)}
    assert not outside, f"omnisim imports ifmi outside {OMNISIM_ALLOWED}: {sorted(outside)}"


def test_omnisim_uses_at_most_five_top_level_parts_of_ifmi():
    parts = {".".join(m.split(".")[:2]) for modules in omnisim_imports_of_ifmi().values() for m in modules}
    assert len(parts) <= 5, sorted(parts)
