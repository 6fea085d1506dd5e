"""The architecture holds (docs/design.md): data flows one way, the rigtool.store package
alone speaks SQL, analysis never writes to the store, and the model runtime imports numpy
only."""

from __future__ import annotations

import ast
import inspect
import re
import subprocess
import sys
from pathlib import Path

import rigtool
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


GRAPH = {m: _imports(p) - {m} for m, p in MODULES.items()}


def test_no_two_modules_or_packages_import_each_other():
    cycles = []
    for a, targets in GRAPH.items():
        for b in targets:
            if a < b and a in GRAPH.get(b, ()):
                cycles.append((a, b))

    def top(m: str) -> str:
        return ".".join(m.split(".")[:2])

    packages: dict[str, set[str]] = {}
    for a, targets in GRAPH.items():
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
        for t in sorted(GRAPH.get(m, ())):
            if state.get(t) == 1:
                cycle.extend(path[path.index(t):] + [m, t] if t in path else [m, t])
                return True
            if t not in state and visit(t, path + [m]):
                return True
        state[m] = 2
        return False

    for m in sorted(GRAPH):
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
    bad = [(m, t) for m, targets in GRAPH.items() for t in targets
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
