"""The direction of dependencies of docs/architecture.md, checked on the source: each
package imports only the packages to its left (and sweepedit.errors), and nothing but
the command line imports the app."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sweepedit"
BELOW = {
    "geometry": set(),
    "io": {"geometry"},
    "analysis": {"geometry", "io"},
    "fitting": {"geometry", "io", "analysis"},
    "batch": {"geometry", "io", "analysis", "fitting"},
    "app": {"geometry", "io", "analysis", "fitting", "api"},
    "training": {"geometry", "io", "analysis", "fitting"},
}


def _imported_packages(path: Path) -> set[str]:
    """The sweepedit subpackages that a module imports (top level or inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0
                 else [])
        for name in names:
            parts = name.split(".")
            if parts[0] == "sweepedit" and len(parts) > 1:
                found.add(parts[1])
    return found


@pytest.mark.parametrize("package", sorted(BELOW))
def test_a_package_imports_only_the_packages_below_it(package: str) -> None:
    allowed = BELOW[package] | {package, "errors"}
    wrong = {str(path.relative_to(PACKAGE)): sorted(_imported_packages(path) - allowed)
             for path in sorted((PACKAGE / package).rglob("*.py"))}
    assert {k: v for k, v in wrong.items() if v} == {}


def test_every_package_is_placed() -> None:
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert packages == set(BELOW)


def _qt_classes(path: Path) -> list[str]:
    """The module's top-level classes that derive from a Qt class (a base named Q...)."""
    def base_name(base: ast.expr) -> str:
        return base.attr if isinstance(base, ast.Attribute) else getattr(base, "id", "")
    return [node.name for node in ast.parse(path.read_text(encoding="utf-8")).body
            if isinstance(node, ast.ClassDef)
            and any(base_name(b).startswith("Q") for b in node.bases)]


@pytest.mark.parametrize("folder", ["app/widgets", "app/panels"])
def test_one_qt_control_per_module(folder: str) -> None:
    modules = {path.name: _qt_classes(path) for path in sorted((PACKAGE / folder).glob("*.py"))}
    assert any(modules.values())
    assert {name: found for name, found in modules.items() if len(found) > 1} == {}


def test_the_public_api_sits_below_the_app_and_the_command_line() -> None:
    """sweepedit/api.py (what `import sweepedit` gives) uses the packages that do the
    work, never the app, batch, training or the command line; sweepedit/__init__.py
    imports nothing of sweepedit at import time (its names load on first use)."""
    assert _imported_packages(PACKAGE / "api.py") <= {"geometry", "io", "analysis", "fitting",
                                                       "errors"}
    init = ast.parse((PACKAGE / "__init__.py").read_text(encoding="utf-8"))
    eager = [node for node in init.body if isinstance(node, ast.Import | ast.ImportFrom)
             and (getattr(node, "module", "") or "").startswith("sweepedit")]
    assert eager == []
