"""The package's folders are its data flow: no module imports a higher layer, no import
cycle, and no clradcom import hidden inside a function to get around either.

Layers, low to high (a module may import its own layer and those below):

    errors, files, memory, figures, the package root
    geometry, paths        plain numpy: triangles, faces, wedges, BVH and kernel layouts;
                           the in-memory paths
    scene                  records, reader, materials, antennas, procedural models
    device                 OpenCL runtime, ray caster, visibility
    physics                Fresnel/roughness dyads, UTD, PO integrals
    mechanisms, maps       specular, diffraction, physical optics/SBR, scattering;
                           radio maps by shooting rays into cells
    snapshot, export       the file; .mat and Sionna-style exports
    trace, presets, series the orchestrator, its named settings, path series over time
    distributed            many traces (a sweep, a drive) as tasks on Dask workers
    radar                  waveform, synthesis, processing, CFAR, interference, truth
    evaluation             accuracy, budget, trade-off (nothing imports it)
    plots, views, commands, cli   what users run (and __main__)

One import is by name on purpose: clradcom/cli.py imports the module of the subcommand
chosen (``importlib.import_module("clradcom.commands." + name)``), so that the command
starts without the tracer; the modules it names are all in clradcom.commands, the cli's
own layer, which test_the_cli_loads_only_command_modules_by_name holds.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from clradcom import cli

PACKAGE = Path(__file__).resolve().parents[1] / "clradcom"

LAYERS = [
    {"clradcom", "clradcom.errors", "clradcom.files", "clradcom.memory", "clradcom.figures"},
    {"clradcom.geometry", "clradcom.paths"},
    {"clradcom.scene"},
    {"clradcom.device"},
    {"clradcom.physics"},
    {"clradcom.mechanisms", "clradcom.maps"},
    {"clradcom.snapshot", "clradcom.export"},
    {"clradcom.trace", "clradcom.presets", "clradcom.series"},
    {"clradcom.distributed"},
    {"clradcom.radar"},
    {"clradcom.evaluation"},
    {"clradcom.plots", "clradcom.views", "clradcom.commands", "clradcom.cli",
     "clradcom.__main__"},
]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def layer_of(module: str) -> int:
    """Index of the layer of a module: its longest listed prefix decides."""
    best, rank = -1, None
    for i, names in enumerate(LAYERS):
        for name in names:
            if (module == name or module.startswith(name + ".")) and len(name) > best:
                best, rank = len(name), i
    if rank is None:
        raise AssertionError(f"{module} is in no layer: add its folder to LAYERS")
    return rank


def clradcom_imports(path: Path, me: str | None = None):
    """(imported module, line, at module level?) for every clradcom import of a file
    (read as module ``me``, by default its own name).
    ``from X import Y`` counts as X.Y when X.Y is a module of the package, else as X."""
    tree = ast.parse(path.read_text(), filename=str(path))
    me = me or module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    top_level = {id(node) for node in tree.body}
    # imports under `if TYPE_CHECKING:` at the top count as top level
    for node in tree.body:
        if isinstance(node, ast.If):
            top_level |= {id(n) for n in node.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            targets = []
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                targets.append(sub if module_exists(sub) else base)
        else:
            continue
        for target in targets:
            if target == "clradcom" or target.startswith("clradcom."):
                yield target, node.lineno, id(node) in top_level


def module_exists(name: str) -> bool:
    rel = Path(*name.split("."))
    return ((PACKAGE.parent / rel).with_suffix(".py").is_file()
            or (PACKAGE.parent / rel / "__init__.py").is_file())


MODULES = sorted(p for p in PACKAGE.rglob("*.py") if "kernels" not in p.parts)


def test_every_module_sits_in_a_layer():
    assert len(MODULES) > 30
    for path in MODULES:
        layer_of(module_name(path))


def layering_violations(path: Path, me: str | None = None) -> list[str]:
    me = me or module_name(path)
    mine = layer_of(me)
    out = []
    for target, line, top in clradcom_imports(path, me):
        if not top:
            out.append(f"{me}:{line}: import of {target} inside a function or class")
        if layer_of(target) > mine:
            out.append(f"{me}:{line}: {me} (layer {mine}) imports {target} "
                       f"(layer {layer_of(target)})")
    return out


@pytest.mark.parametrize("path", MODULES, ids=lambda p: module_name(p))
def test_no_import_runs_upward_or_hides_in_a_function(path):
    assert layering_violations(path) == []


def test_nothing_imports_evaluation():
    for path in MODULES:
        me = module_name(path)
        if me.startswith("clradcom.evaluation") or layer_of(me) > layer_of("clradcom.evaluation"):
            continue
        for target, line, _ in clradcom_imports(path):
            assert not target.startswith("clradcom.evaluation"), f"{me}:{line} imports {target}"


def test_no_import_cycle():
    graph = {module_name(p): {t for t, _, _ in clradcom_imports(p)} for p in MODULES}
    state: dict[str, int] = {}  # 1 on the stack, 2 done

    def visit(node, stack):
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if nxt not in graph:
                continue
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt):] + [nxt]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])


def test_the_checker_sees_an_upward_and_a_hidden_import(tmp_path):
    """The check itself can fail: a geometry module importing the tracer inside a
    function is caught twice, and relative imports resolve from the module's folder."""
    probe = tmp_path / "probe.py"
    probe.write_text("from .bvh import build_bvh\n\n\ndef f():\n"
                     "    from clradcom.trace import trace_scene\n")
    found = layering_violations(probe, "clradcom.geometry.probe")
    assert len(found) == 2
    assert "inside a function" in found[0] and "clradcom.trace" in found[0]
    assert "imports clradcom.trace" in found[1]
    assert [t for t, _, _ in clradcom_imports(probe, "clradcom.geometry.probe")] == [
        "clradcom.geometry.bvh", "clradcom.trace"]


def test_architecture_doc_names_every_module():
    """docs/architecture.md stays true to the code: every module has its line there."""
    doc = (PACKAGE.parent / "docs" / "architecture.md").read_text()
    missing = [str(p.relative_to(PACKAGE.parent)) for p in MODULES
               if p.name != "__init__.py" and f"`{p.relative_to(PACKAGE.parent)}`" not in doc]
    assert missing == []


def test_the_cli_loads_only_command_modules_by_name():
    for name in cli.SUBCOMMANDS:
        module = cli.command_module(name)
        assert module.__name__.startswith("clradcom.commands.")
        assert layer_of(module.__name__) == layer_of("clradcom.cli")
    text = (PACKAGE / "cli.py").read_text()
    assert text.count("importlib.import_module(") == 1
