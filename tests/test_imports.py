"""The layering, read from the source with ``ast`` (nothing is imported): commands -> analysis ->
run core -> algorithms and envs. The environment and the optimisers never import the lifelong tools, the run
core (``lifelong_evo`` outside ``commands/``) never imports a command, only the Ray module imports
Ray, and no module of the project imports, directly or through others, a module that imports it,
counting the imports inside functions too."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("envs", "algorithms", "lifelong_evo")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(path): path for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))}
ENTRY_POINTS = ("lifelong_evo.__main__", "lifelong_evo.bench")
"""``python -m lifelong_evo`` and ``python -m lifelong_evo.bench``: they only hand over to a command."""
RAY_MODULE = "lifelong_evo.commands.ray_cluster"


def _imported(name: str) -> set[str]:
    """Every module name that module ``name`` imports, anywhere in its source, as written (absolute)."""
    path = MODULES[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([base] if base else [])])
            found.update(f"{base}.{alias.name}" for alias in node.names)
            found.add(base)
    return found


def _imports(name: str) -> set[str]:
    """The project modules that module ``name`` imports, anywhere in its source."""
    path = MODULES[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([base] if base else [])])
            # ``from package import module`` imports the module; ``from module import name`` the module
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base for alias in node.names]
        else:
            continue
        for target in targets:
            while target and target not in MODULES:  # ``import lifelong_evo.commands.cli.main`` is lifelong_evo.commands.cli
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


GRAPH = {name: _imports(name) for name in MODULES}


def test_the_environment_and_the_optimisers_never_import_the_lifelong_tools():
    offending = {name: sorted(t for t in targets if t.split(".")[0] == "lifelong_evo")
                 for name, targets in GRAPH.items() if name.split(".")[0] in ("envs", "algorithms")}
    assert not {k: v for k, v in offending.items() if v}
    assert not [t for t in GRAPH["envs"] | set().union(*(GRAPH[n] for n in MODULES if n.startswith("envs.")))
                if t.split(".")[0] == "algorithms"], "the environment knows nothing of the optimisers"


def test_the_run_core_reaches_the_optimisers_through_their_interface():
    """The run core and the analysis import ``algorithms`` (the registry, exports, the drawings of
    controllers) and ``algorithms.base`` only, never a family's own modules: what is NEAT's or an
    MLP's stays behind ``algorithms`` (the benchmark, a command, builds MLP policies itself)."""
    core = [name for name in MODULES if name.split(".")[0] == "lifelong_evo"
            and not name.startswith("lifelong_evo.commands")]
    assert "lifelong_evo.networks" in core and "lifelong_evo.analysis.figures" in core
    offending = {name: sorted(t for t in GRAPH[name] if t.split(".")[0] == "algorithms"
                              and t not in ("algorithms", "algorithms.base")) for name in core}
    assert not {k: v for k, v in offending.items() if v}


def test_the_run_core_never_imports_a_command():
    core = [name for name in MODULES if name.split(".")[0] == "lifelong_evo"
            and not name.startswith("lifelong_evo.commands") and name not in ENTRY_POINTS]
    assert "lifelong_evo.loop" in core and "lifelong_evo.rundir" in core
    offending = {name: sorted(t for t in GRAPH[name] if t.startswith("lifelong_evo.commands")) for name in core}
    assert not {k: v for k, v in offending.items() if v}


RUN_DIRECTORY_LAYERS = (
    ("lifelong_evo.run_names", "lifelong_evo.run_lock", "lifelong_evo.provenance", "lifelong_evo.json_files",
     "lifelong_evo.metrics_csv", "lifelong_evo.run_files"),
    ("lifelong_evo.rundir",),
    ("lifelong_evo.runs",),
)
"""The run directory's modules, lowest first, one job each: its name, its lock, provenance, its
JSON files, metrics.csv's schema, writer and reader, and the checks of what is read; then
``RunDir`` (making, writing and the resume rule) on them; then reading runs back. A module imports
only from the layers below its own, never from its own layer or above."""


def test_the_run_directory_modules_import_only_downwards():
    layer_of = {name: level for level, names in enumerate(RUN_DIRECTORY_LAYERS) for name in names}
    assert set(layer_of) <= set(MODULES)
    offending = {name: sorted(t for t in GRAPH[name] if t in layer_of and layer_of[t] >= layer_of[name])
                 for name in layer_of}
    assert not {k: v for k, v in offending.items() if v}


def test_callers_import_a_moved_name_from_its_own_module():
    """``rundir`` hands on no name of its neighbours: nobody imports from it a name it imports."""
    rundir = ast.parse(MODULES["lifelong_evo.rundir"].read_text())
    imported = {alias.asname or alias.name for node in rundir.body if isinstance(node, ast.ImportFrom)
                for alias in node.names}
    offending = {}
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("rundir"):
                taken = sorted(alias.name for alias in node.names if alias.name in imported)
                if taken:
                    offending[name] = taken
    assert not offending


def test_the_analysis_stands_between_the_run_core_and_the_commands():
    """``lifelong_evo.analysis`` (statistics, tables, figures) imports no command, and the run core
    imports none of it: the verbs call it, and so can a notebook."""
    analysis = {name for name in MODULES if name.startswith("lifelong_evo.analysis")}
    assert {"lifelong_evo.analysis.comparison", "lifelong_evo.analysis.figures"} <= analysis
    offending = {name: sorted(t for t in GRAPH[name] if t.startswith("lifelong_evo.commands")) for name in analysis}
    assert not {k: v for k, v in offending.items() if v}
    core = [name for name in MODULES if name.split(".")[0] == "lifelong_evo" and name not in ENTRY_POINTS
            and not name.startswith(("lifelong_evo.commands", "lifelong_evo.analysis"))]
    offending = {name: sorted(t for t in GRAPH[name] if t in analysis) for name in core}
    assert not {k: v for k, v in offending.items() if v}


def test_only_the_ray_module_imports_ray():
    importers = sorted(name for name in MODULES if any(t == "ray" or t.startswith("ray.") for t in _imported(name)))
    assert importers == [RAY_MODULE]


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return components


def test_no_import_cycles():
    assert _cycles(GRAPH) == []


def test_the_cycle_finder_finds_one():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert "lifelong_evo.loop" in GRAPH["lifelong_evo.commands.cli"] and "algorithms.es" in GRAPH["algorithms.cmaes"]
