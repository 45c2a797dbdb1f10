"""The package's layers point one way, and no module grows past 600 lines (issue 30).

Every ``import`` of an ``l3cli`` module anywhere in a module (at the top, in
a function, under ``TYPE_CHECKING``) is an edge of the import graph. The
graph must have no cycle, and each edge must go to the same layer or a lower
one, in the order written once in :data:`LAYERS` (docs/architecture.md,
"Layers"). A module that is in no layer fails the test: a new module is
placed by adding it here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "l3cli"

#: The layers, lowest first. A module may import its own layer and the ones
#: before it. Entries are module names under ``l3cli`` (a package name takes
#: its whole subtree; the longest matching entry wins).
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    # no l3 concepts: errors, option defaults, process start-up, stored machine
    # code, progress, buffer pools, the CFA, colour spaces, spectra, map-reduce
    ("base", ("l3cli", "errors", "defaults", "startup", "kernel_store", "progress", "buffers",
              "cfa", "colourspace", "spectral", "parallel", "threads", "figures", "tablekeys")),
    # files: raws, images, metadata, display encoding, manifests, atomic writes
    ("io", ("io",)),
    # the L3 model: classes, the tile kernel, render rows, the table, tone
    # curve, white balance, condition bins, lens shading, the multi-scale stage,
    # kernel sets; the metrics; a camera's description (its TOML, validated)
    # (a table feature's package is here but for its fit, a workflow: see below)
    ("model", ("classify", "render_rows", "table", "conditions", "kernelset", "prepared",
               "metrics", "camera", "illumination", "model", "features",
               "tone", "whitebalance", "multiscale", "lens")),
    # inputs: training pairs, registration, previews, simulation
    ("inputs", ("pairs", "align", "preview", "simulate", "rawinfo")),
    # workflows: train, render, evaluate, smooth, baseline, inspect, export, and the
    # table features' fits (from training pairs)
    ("workflows", ("train", "render", "pipeline", "evaluate", "smooth", "baseline", "inspect",
                   "plots_table", "export", "tone.fit", "whitebalance.fit", "multiscale.fit",
                   "multiscale.cv", "lens.train")),
    # the command line
    ("cli", ("cli",)),
)

#: Edges that break the rule today, each with the issue that removes it.
KNOWN_EXCEPTIONS: frozenset[tuple[str, str]] = frozenset()

#: Modules over the line limit today, with the most lines they may have until split.
LONG_MODULES: dict[str, int] = {}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def package_modules() -> dict[str, Path]:
    """Every module of the package (``l3cli/data`` holds data and its scripts: left out)."""
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))
            if p.relative_to(PACKAGE).parts[0] != "data"}


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    parts = name.split(".")
    while parts:
        if ".".join(parts) in modules:
            return ".".join(parts)
        parts.pop()
    return None


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The l3cli modules that module ``name`` imports, anywhere in its body."""
    out: set[str] = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # "from l3cli.x import y": y may be a module of its own
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
        for t in targets:
            if t == "l3cli" or t.startswith("l3cli."):
                found = _resolve(t, modules)
                if found is not None and found != name:
                    out.add(found)
    return out


def import_graph() -> dict[str, set[str]]:
    modules = package_modules()
    return {name: imports_of(name, path, modules) for name, path in modules.items()}


def layer_of(module: str) -> int | None:
    best, best_len = None, -1
    for rank, (_, entries) in enumerate(LAYERS):
        for entry in entries:
            full = "l3cli" if entry == "l3cli" else f"l3cli.{entry}"
            if (module == full or module.startswith(full + ".")) and len(full) > best_len:
                best, best_len = rank, len(full)
    return best


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
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
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_reads_imports_inside_functions_and_relative_ones(tmp_path):
    modules = {"l3cli": Path("l3cli/__init__.py"), "l3cli.a": Path("l3cli/a.py"),
               "l3cli.b": Path("l3cli/b.py"), "l3cli.io": Path("l3cli/io/__init__.py"),
               "l3cli.io.raw": Path("l3cli/io/raw.py")}
    a = tmp_path / "a.py"
    a.write_text("import numpy\nfrom l3cli import b\ndef f():\n    from l3cli.io.raw import read_raw\n"
                 "    import l3cli.io\n")
    assert imports_of("l3cli.a", a, modules) == {"l3cli.b", "l3cli.io.raw", "l3cli.io"}
    x = tmp_path / "x.py"  # a module l3cli.io.x
    x.write_text("from . import raw\nfrom ..a import y\n")
    assert imports_of("l3cli.io.x", x, modules) == {"l3cli.io.raw", "l3cli.a"}
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
    assert [layer_of(m) for m in ("l3cli.io.raw", "l3cli.classify.kernel", "l3cli.cli.main")] == [1, 2, 5]


def test_every_module_has_a_layer():
    missing = sorted(m for m in package_modules() if layer_of(m) is None)
    assert not missing, f"modules in no layer (add them to LAYERS in {Path(__file__).name}): {missing}"


def test_no_import_cycles():
    found = cycles({m: {d for d in deps if (m, d) not in KNOWN_EXCEPTIONS}
                    for m, deps in import_graph().items()})
    assert not found, f"import cycles: {found}"


def test_imports_go_down_the_layers():
    names = [n for n, _ in LAYERS]
    bad = []
    for module, deps in sorted(import_graph().items()):
        lm = layer_of(module)
        for dep in sorted(deps):
            ld = layer_of(dep)
            if lm is not None and ld is not None and ld > lm and (module, dep) not in KNOWN_EXCEPTIONS:
                bad.append(f"{module} ({names[lm]}) imports {dep} ({names[ld]})")
    assert not bad, "imports up the layers:\n" + "\n".join(bad)


def test_the_file_layer_knows_nothing_above_it():
    # spelled out, as the issue asks: l3cli/io imports no model, input or workflow module
    io_rank = [n for n, _ in LAYERS].index("io")
    for module, deps in import_graph().items():
        if module.startswith("l3cli.io"):
            assert all(layer_of(d) is not None and layer_of(d) <= io_rank
                       for d in deps if (module, d) not in KNOWN_EXCEPTIONS), (module, deps)


def test_known_exceptions_are_still_needed():
    graph = import_graph()
    stale = [edge for edge in KNOWN_EXCEPTIONS if edge[1] not in graph.get(edge[0], set())]
    assert not stale, f"exceptions no longer needed (remove them): {stale}"


@pytest.mark.parametrize("limit", [600])
def test_no_module_over_600_lines(limit):
    lines = {name: len(path.read_text(encoding="utf-8").splitlines())
             for name, path in package_modules().items()}
    long = {name: n for name, n in lines.items() if n > max(limit, LONG_MODULES.get(name, 0))}
    assert not long, f"modules over {limit} lines (split them): {long}"
    split = [name for name in LONG_MODULES if lines.get(name, 0) <= limit]
    assert not split, f"modules back under {limit} lines (remove them from LONG_MODULES): {split}"
