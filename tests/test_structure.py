"""The structure six chips plug into, checked over imud's source: generic modules that neither
name a chip nor probe one with getattr, device states as an enum, and a chip folder per chip.
The layers and the absence of import circles are import-linter's contracts (pyproject.toml,
run by .ci/run)."""

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


CHIP_DIRS = {p.parent.name for p in ROOT.glob("chips/*/spec.py")}


def generic_modules() -> dict[str, Path]:
    return {
        m: p
        for m, p in MODULES.items()
        if not any(m.startswith(f"imud.chips.{c}") for c in CHIP_DIRS)
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
