"""The architecture holds (docs/design.md): data flows one way, the rigtool.store package
alone speaks SQL, analysis never writes to the store, and the model runtime imports numpy
only."""

from __future__ import annotations

import ast
import functools
import inspect
import re
import subprocess
import sys
from pathlib import Path

import rigtool
from rigtool.devices.registry import driver_modules
from rigtool.store import Store

PACKAGE = Path(rigtool.__file__).parent
SQL = re.compile(r"\b(SELECT|INSERT INTO|DELETE FROM|UPDATE \w+ SET|CREATE TABLE|ALTER TABLE|"
                 r"ATTACH DATABASE)\b|\.execute(many|script)?\(|\.conn\b|sqlite_utils")


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


MODULES = _modules()


def _imports(path: Path) -> set[str]:
    """rigtool modules `path` imports, at any level (function-local imports count too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            while name and name not in MODULES:
                name = name.rpartition(".")[0]
            if name.startswith("rigtool.") :
                found.add(name)
                break
    return found


@functools.cache
def _graph() -> dict[str, set[str]]:
    """Module -> the rigtool modules it imports; parsed when a test first asks (not at collection)."""
    return {m: _imports(p) - {m} for m, p in MODULES.items()}


def test_no_two_modules_or_packages_import_each_other():
    cycles = []
    for a, targets in _graph().items():
        for b in targets:
            if a < b and a in _graph().get(b, ()):
                cycles.append((a, b))

    def top(m: str) -> str:
        return ".".join(m.split(".")[:2])

    packages: dict[str, set[str]] = {}
    for a, targets in _graph().items():
        packages.setdefault(top(a), set()).update(top(b) for b in targets if top(b) != top(a))
    cycles += [(a, b) for a, bs in packages.items() for b in bs
               if a < b and a in packages.get(b, ())]
    assert cycles == []


def test_no_import_cycles_at_all():
    """Longer cycles too: a depth-first search over the whole import graph."""
    state: dict[str, int] = {}
    cycle: list[str] = []

    def visit(m: str, path: list[str]) -> bool:
        state[m] = 1
        for t in sorted(_graph().get(m, ())):
            if state.get(t) == 1:
                cycle.extend(path[path.index(t):] + [m, t] if t in path else [m, t])
                return True
            if t not in state and visit(t, path + [m]):
                return True
        state[m] = 2
        return False

    for m in sorted(_graph()):
        if m not in state and visit(m, []):
            break
    assert cycle == []


def _in_store(module: str) -> bool:
    """Whether a module is the rigtool.store package or one of its modules."""
    return module == "rigtool.store" or module.startswith("rigtool.store.")


def test_only_the_store_speaks_sql():
    speaking = sorted(m for m, p in MODULES.items()
                      if not _in_store(m) and SQL.search(p.read_text()))
    assert speaking == []
    assert any(_in_store(m) and SQL.search(p.read_text()) for m, p in MODULES.items())


def test_analysis_never_writes_to_the_store():
    """Store methods that open a write transaction may not be called from rigtool.analysis."""
    writers = {name for name, fn in inspect.getmembers(Store, inspect.isfunction)
               if "self.transaction()" in inspect.getsource(fn)} | {"transaction"}
    assert {"add_calibration", "replace_events", "finish_run"} <= writers
    calls = []
    for m, path in MODULES.items():
        if m.startswith("rigtool.analysis"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Attribute) and node.attr in writers:
                    calls.append(f"{m}: {node.attr}")
    assert calls == []


def test_data_flows_one_way():
    """Analysis reads the store and never imports what sits after it (artefacts, reports,
    workflows, CLI); the store and the model runtime import no analysis."""
    later = ("rigtool.artefacts", "rigtool.report", "rigtool.workflows", "rigtool.cli",
             "rigtool.api", "rigtool.export")
    bad = [(m, t) for m, targets in _graph().items() for t in targets
           if (m.startswith("rigtool.analysis") and t.startswith(later))
           or (_in_store(m) or m.startswith("rigtool.models"))
           and t.startswith(("rigtool.analysis", "rigtool.artefacts", "rigtool.report"))]
    assert bad == []


def test_model_runtime_imports_numpy_and_the_standard_library_only():
    code = ("import sys; before = set(sys.modules); import rigtool.models; "
            "new = {m.split('.')[0] for m in set(sys.modules) - before}; "
            "print(sorted(m for m in new if m not in sys.stdlib_module_names "
            "and not m.startswith('_')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['numpy', 'rigtool']"


# The ranks of docs/design.md, lowest first: a module may import its own rank and those below,
# never one above. Every module has a rank (a new top-level module must be placed here).
RANKS = {
    "foundation": ("rigtool.errors", "rigtool.units", "rigtool.bounds", "rigtool.clock",
                   "rigtool.files", "rigtool.outpaths", "rigtool.readback", "rigtool.spool",
                   "rigtool.ids", "rigtool.dbpath", "rigtool.counters",
                   "rigtool.thruster_profiles", "rigtool.version", "rigtool.models",
                   "rigtool.stopping", "rigtool.sections",
                   "rigtool.progress_hook"),
    "config": ("rigtool.config", "rigtool.protocol", "rigtool.plan", "rigtool.accuracy",
               "rigtool.vehicle_file"),
    "devices": ("rigtool.devices", "rigtool.sim", "rigtool.rig"),
    "store": ("rigtool.store",),
    "analysis": ("rigtool.analysis", "rigtool.run_warnings"),
    "artefacts": ("rigtool.artefacts",),
    "report": ("rigtool.report",),
    "workflows": ("rigtool.workflows", "rigtool.engine", "rigtool.safety", "rigtool.sweep",
                  "rigtool.progress", "rigtool.check", "rigtool.importers",
                  "rigtool.limit_sources", "rigtool.sensor_rate", "rigtool.vehicle_workflow"),
    "interfaces": ("rigtool", "rigtool.__main__", "rigtool.launch", "rigtool.cli", "rigtool.api",
                   "rigtool.watch", "rigtool.export", "rigtool.dataset", "rigtool.display"),
}
ORDER = list(RANKS)


def _rank(module: str) -> int | None:
    """The rank of `module`: that of the longest prefix named in RANKS (the root package
    itself, `rigtool`, names only itself)."""
    best = None
    for i, layer in enumerate(ORDER):
        for prefix in RANKS[layer]:
            if (module == prefix or module.startswith(prefix + ".") and prefix != "rigtool") and (
                    best is None or len(prefix) > len(best[1])):
                best = (i, prefix)
    return None if best is None else best[0]


def _all_imports(module: str, path: Path) -> set[str]:
    """Every rigtool module `module` imports: absolute, relative (`from . import x`), the
    root package (`import rigtool`, `from rigtool import x`), and string names handed to
    importlib or kept in a lazy table (`"rigtool.devices.netft"`, `"rigtool.x:Class"`)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()

    def add(name: str) -> None:
        while name and name not in MODULES:
            name = name.rpartition(".")[0]
        if name:
            found.add(name)

    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            if base.split(".")[0] == "rigtool":
                for alias in node.names:
                    add(f"{base}.{alias.name}") if f"{base}.{alias.name}" in MODULES else add(base)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "rigtool":
                    add(alias.name)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            name = node.value.partition(":")[0]
            if re.fullmatch(r"rigtool(\.\w+)+", name) and name in MODULES:
                add(name)
    return found - {module}


@functools.cache
def _full() -> dict[str, set[str]]:
    """Module -> every rigtool module it imports by any route; parsed when first asked."""
    return {m: _all_imports(m, p) for m, p in MODULES.items()}


def test_every_module_has_a_rank():
    assert sorted(m for m in MODULES if _rank(m) is None) == []


def test_no_module_imports_a_higher_rank():
    """foundation < config < devices/sim < store < analysis < artefacts < report < workflows
    < interfaces (CLI, API, watch, export)."""
    bad = sorted(f"{m} ({ORDER[_rank(m)]}) -> {t} ({ORDER[_rank(t)]})"
                 for m, targets in _full().items() for t in targets
                 if _rank(m) is not None and _rank(t) is not None and _rank(t) > _rank(m))
    assert bad == []


def test_the_import_finder_sees_relative_root_and_importlib_imports():
    import textwrap

    src = textwrap.dedent("""
        import importlib
        import rigtool
        from rigtool import errors
        from . import base
        from .. import units
        TABLE = {"x": "rigtool.engine:Engine"}
        importlib.import_module("rigtool.store")
    """)
    path = Path(__file__).parent / "_layering_probe.py"
    path.write_text(src)
    try:
        got = _all_imports("rigtool.devices.probe", path)
    finally:
        path.unlink()
    assert {"rigtool", "rigtool.errors", "rigtool.devices.base", "rigtool.units",
            "rigtool.engine", "rigtool.store"} <= got


def test_devices_import_no_store_engine_or_analysis_and_config_no_simulator():
    bad = sorted((m, t) for m, targets in _full().items() for t in targets
                 if (m.startswith("rigtool.devices") and t.startswith(
                     ("rigtool.store", "rigtool.engine", "rigtool.analysis", "rigtool.sweep")))
                 or (_rank(m) == ORDER.index("config") and t.startswith("rigtool.sim")))
    assert bad == []


def _drivers_importing_drivers(graph: dict[str, set[str]], drivers: set[str]) -> list[tuple]:
    """(driver, driver it imports) pairs: `drivers` are the registry's modules."""
    return sorted((m, t) for m, targets in graph.items() if m in drivers
                  for t in targets if t in drivers)


def test_a_driver_imports_no_other_driver():
    """Shared pieces (units, framing, the CAN link, the base) live in shared modules, not in
    one driver that the others import; the drivers are those devices/registry.py lists."""
    drivers = driver_modules()
    assert len(drivers) >= 8 and drivers <= set(MODULES)
    assert _drivers_importing_drivers(_full(), drivers) == []


def test_the_driver_rule_fails_on_a_registered_driver_that_imports_another(tmp_path):
    """A new driver registered in the table and importing an existing driver is caught."""
    path = tmp_path / "load_cell.py"
    path.write_text("from rigtool.devices.ascii_gauge import LineParser\n")
    graph = {**_full(), "rigtool.devices.load_cell": _all_imports("rigtool.devices.load_cell", path)}
    drivers = driver_modules() | {"rigtool.devices.load_cell"}
    assert _drivers_importing_drivers(graph, drivers) == [
        ("rigtool.devices.load_cell", "rigtool.devices.ascii_gauge")]


# Who may call what (docs/design.md): runs are written by the run layer (the engine during a
# sweep, sweep.py when it creates, resumes or closes one), the importers and the post-run
# workflows; devices are driven by the engine and by `rigtool check`'s pre-flight read.
RUN_WRITERS = {"create_run", "add_step", "add_points", "finish_run", "reopen_run", "add_event",
               "add_events", "add_calibration", "replace_events"}
MAY_WRITE_RUNS = ("rigtool.engine", "rigtool.sweep", "rigtool.importers", "rigtool.workflows",
                  "rigtool.store")
DRIVING = {"set_command", "set_voltage", "move_to", "set_bias"}
MAY_DRIVE = ("rigtool.engine", "rigtool.check", "rigtool.devices", "rigtool.sim")


def _calls(names: set[str], allowed: tuple[str, ...]) -> list[str]:
    out = []
    for m, path in MODULES.items():
        if m.startswith(allowed):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr in names):
                out.append(f"{m}: {node.func.attr}")
    return sorted(out)


def test_runs_are_written_only_by_the_run_layer_importers_and_workflows():
    assert _calls(RUN_WRITERS, MAY_WRITE_RUNS) == []


def test_devices_are_driven_only_by_the_engine_and_check():
    assert _calls(DRIVING, MAY_DRIVE) == []


def test_the_design_document_states_these_ranks():
    text = (PACKAGE.parent / "docs" / "design.md").read_text()
    assert ("foundation < config < devices/sim < store < analysis < artefacts < report < "
            "workflows < interfaces") in " ".join(text.split())
