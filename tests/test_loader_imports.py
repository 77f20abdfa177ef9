"""The loaders stand below the core: no module of loaders/ imports the package beyond
the error and output helpers and the loaders themselves, so the core can change without
the loaders following it (and the loaders be used without a GPU)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

LOADERS = Path(__file__).resolve().parents[1] / "loaders"
ALLOWED = ("progressive.errors", "progressive.output", "progressive.loaders")


def package_imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import of the package in a module, at any depth (a
    function's lazy import counts too); relative imports count as the package's."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = "progressive.loaders" if node.level else (node.module or "")
            if base == "progressive":
                found += [(node.lineno, f"progressive.{alias.name}") for alias in node.names]
            else:
                found.append((node.lineno, base))
    return [(line, name) for line, name in found if name == "progressive" or name.startswith("progressive.")]


def allowed(module: str) -> bool:
    return any(module == a or module.startswith(a + ".") for a in ALLOWED)


@pytest.mark.parametrize("path", sorted(LOADERS.glob("*.py")), ids=lambda p: p.name)
def test_loaders_import_only_errors_output_and_loaders(path):
    bad = [f"{path.name}:{line} imports {name}" for line, name in package_imports(path) if not allowed(name)]
    assert not bad, "; ".join(bad)


def test_the_rule_sees_what_it_forbids(tmp_path):
    """The check finds the imports it exists to refuse, in each form they take."""
    module = tmp_path / "m.py"
    module.write_text("from progressive.permutation import LAYOUT\nimport progressive.scene\n"
                      "from progressive import packing\n"
                      "def f():\n    from progressive.errors import InputError\n", encoding="utf-8")
    names = [name for _, name in package_imports(module)]
    assert [n for n in names if not allowed(n)] == ["progressive.permutation", "progressive.scene", "progressive.packing"]
    assert "progressive.errors" in names
