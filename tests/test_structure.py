"""The structure six chips plug into, checked over imud's source: no import circles, generic
modules that neither name a chip nor probe one with getattr, device states as an enum, and a
chip folder per registered chip."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from imud import registry

ROOT = Path(__file__).resolve().parent.parent / "imud"


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {module_name(p): p for p in ROOT.rglob("*.py")}


def _type_checking_only(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def imports(path: Path) -> set[str]:
    """imud modules a module imports, at any depth, except under `if TYPE_CHECKING:`; importing
    a submodule also runs its packages' __init__, so those count too."""
    tree = ast.parse(path.read_text())
    found: set[str] = set()
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]

    def visit(node: ast.AST) -> None:
        if _type_checking_only(node):
            return
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            targets = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names
            ]
        for t in targets:
            parts = t.split(".")
            for i in range(1, len(parts) + 1):
                name = ".".join(parts[:i])
                if name in MODULES and name != here:
                    found.add(name)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def test_no_import_circles() -> None:
    graph = {m: imports(p) for m, p in MODULES.items()}
    # Tarjan's strongly connected components: any component of two or more is a circle
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    circles: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                circles.append(sorted(comp))

    for m in graph:
        if m not in index:
            strong(m)
    assert not circles, circles


def test_the_graph_sees_real_imports() -> None:
    """Guard for the test above: it must find the edges that do exist."""
    assert "imud.busworker" in imports(MODULES["imud.buschild"])
    assert "imud.chips.api" in imports(MODULES["imud.chips.mpu6050.driver"])
    assert "imud.chips" in imports(MODULES["imud.chips.mpu6050.driver"])  # the package runs too


CHIP_DIRS = {p.parent.name for p in ROOT.glob("chips/*/spec.py")}


def generic_modules() -> dict[str, Path]:
    return {
        m: p
        for m, p in MODULES.items()
        if not any(m.startswith(f"imud.chips.{c}") for c in CHIP_DIRS) and m != "imud.registry"
    }


def _code_strings_and_names(tree: ast.AST) -> set[str]:
    """Identifiers and string constants, docstrings excepted."""
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docstrings.add(id(body[0].value))
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            out.add(node.id)
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
        elif isinstance(node, ast.alias):
            out.update(node.name.split("."))
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.update(node.module.split("."))
        elif (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and id(node) not in docstrings
        ):
            out.add(node.value)
    return out


@pytest.mark.parametrize("module", sorted(generic_modules()))
def test_generic_modules_never_name_a_chip(module: str) -> None:
    words = {w.lower() for w in _code_strings_and_names(ast.parse(MODULES[module].read_text()))}
    named = {c for c in CHIP_DIRS | set(registry.CHIPS) if any(c in w for w in words)}
    assert not named, f"{module} names {named}"


@pytest.mark.parametrize("module", sorted(generic_modules()))
def test_generic_modules_never_probe_with_getattr(module: str) -> None:
    tree = ast.parse(MODULES[module].read_text())
    probes = [
        ast.unparse(n)
        for n in ast.walk(tree)
        if isinstance(n, ast.Call)
        and isinstance(n.func, ast.Name)
        and n.func.id in ("getattr", "hasattr")
        and not (isinstance(n.args[0], ast.Name) and n.args[0].id == "self")
    ]
    assert not probes, probes


def test_device_states_are_compared_as_the_enum() -> None:
    from imud.status import DeviceState

    states = {s.value for s in DeviceState}
    bad = []
    for m, p in MODULES.items():
        for n in ast.walk(ast.parse(p.read_text())):
            if isinstance(n, ast.Compare):
                for c in [n.left, *n.comparators]:
                    if isinstance(c, ast.Constant) and c.value in states:
                        bad.append(f"{m}: {ast.unparse(n)}")
    assert not bad, bad


def test_each_registered_chip_is_one_folder_and_one_registry_entry() -> None:
    assert set(registry.CHIPS) == CHIP_DIRS
    for chip in CHIP_DIRS:
        files = {p.name for p in (ROOT / "chips" / chip).glob("*.py")}
        assert {"registers.py", "config.py", "driver.py", "sim.py", "spec.py"} <= files, chip
        spec = registry.CHIPS[chip]
        assert spec.config_model.__module__ == f"imud.chips.{chip}.config"
        assert "odr_hz" in spec.config_model.model_fields
