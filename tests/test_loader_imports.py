"""The loaders stand below the core: no module of loaders/ imports the package beyond
the error and output helpers and the loaders themselves, so the core can change without
the loaders following it (and the loaders be used without a GPU)."""

from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
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


def fresh_python(code: str) -> str:
    """What `code` prints in a fresh interpreter (nothing imported before it)."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_commands_import_laspy_without_requests_or_pyproj(tmp_path):
    """A command's imports leave out what laspy imports for nothing progressive uses
    (loaders/lean_imports.py), and the two still import afterwards: laspy reads a
    header's CRS through pyproj, and `import requests` works where it is installed."""
    import laspy
    import pyproj

    header = laspy.LasHeader(point_format=3, version="1.4")
    header.add_crs(pyproj.CRS.from_epsg(32610))
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.zeros(3), np.zeros(3), np.zeros(3)
    las.write(tmp_path / "crs.las")
    has_requests = importlib.util.find_spec("requests") is not None
    printed = fresh_python(
        "import sys, progressive.cli, progressive.session\n"
        "print(sorted(m for m in ('laspy', 'pyproj', 'requests') if m in sys.modules))\n"
        "import laspy\n"
        f"print(laspy.open({str(tmp_path / 'crs.las')!r}).header.parse_crs().to_epsg())\n"
        + ("import requests\nprint(requests.__name__)\n" if has_requests else "")).splitlines()
    assert printed[:2] == ["['laspy']", "32610"]
    assert printed[2:] == (["requests"] if has_requests else [])


@pytest.mark.skipif(importlib.util.find_spec("requests") is None, reason="requests is not installed")
def test_an_earlier_import_of_requests_is_left_to_laspy():
    """Where requests came first, laspy keeps its HTTP support."""
    assert fresh_python("import requests, progressive.cli, laspy.copc\nprint(laspy.copc.requests is requests)") == "True"
