"""The package's rooms import only downwards (../shared/DESIGN.md, "Layers"), and the benchmarks use only the
public API. A new upward import (learning reaching into control, a command into the CLI) fails here."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "dyndlo_vision"
BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

#: Which rooms each room may import (besides itself and the package's private helpers ``_atomic``, ``_gl``).
ALLOWED: dict[str, set[str]] = {
    "trajectory": set(),
    "tracking": set(),
    "sim": {"trajectory"},
    "cameras": {"sim", "tracking"},
    "robots": {"trajectory"},
    "tasks": {"sim", "trajectory", "robots"},
    "policies": {"tasks"},
    "control": {"cameras", "robots", "sim", "tasks", "tracking", "trajectory", "policies"},
    "learning": {"tasks", "policies", "sim", "trajectory", "tracking", "__init__"},
    "commands": {"cameras", "control", "learning", "policies", "robots", "sim", "tasks", "tracking",
                 "trajectory", "__init__"},
    "cli": {"commands", "__init__"},
    "__init__": {"tasks"},
    "__main__": {"cli"},
}
PRIVATE_HELPERS = {"_atomic", "_gl"}


def imported_modules(path: Path, module: str) -> set[str]:
    """Absolute names of the ``dyndlo_vision`` modules a file imports (relative imports resolved)."""
    names: set[str] = set()
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            target = ".".join([*base, node.module] if node.module else base)
            names.add(target)
            names.update(f"{target}.{a.name}" for a in node.names)
    return {n for n in names if n == "dyndlo_vision" or n.startswith("dyndlo_vision.")}


def room(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def upward_imports(root: Path) -> list[str]:
    found = []
    for path in sorted(root.rglob("*.py")):
        module = ".".join(path.relative_to(root.parent).with_suffix("").parts).removesuffix(".__init__")
        own = room(module)
        for target in imported_modules(path, module):
            other = room(target)
            if other in (own, *PRIVATE_HELPERS) or other in ALLOWED[own]:
                continue
            if other not in ALLOWED:  # a name imported from the package's top level, e.g. a function
                continue
            found.append(f"{module} imports {target} ({own} -> {other})")
    return sorted(found)


def test_rooms_import_only_downwards() -> None:
    assert upward_imports(PACKAGE) == []


def test_the_check_sees_an_upward_import(tmp_path: Path) -> None:
    fake = tmp_path / "dyndlo_vision"
    (fake / "learning").mkdir(parents=True)
    (fake / "learning" / "train.py").write_text("from dyndlo_vision.control.loop import ControlLoop\n")
    (fake / "learning" / "plots.py").write_text("from ..cli import main\n")
    assert upward_imports(fake) == [
        "dyndlo_vision.learning.plots imports dyndlo_vision.cli (learning -> cli)",
        "dyndlo_vision.learning.plots imports dyndlo_vision.cli.main (learning -> cli)",
        "dyndlo_vision.learning.train imports dyndlo_vision.control.loop (learning -> control)",
        "dyndlo_vision.learning.train imports dyndlo_vision.control.loop.ControlLoop (learning -> control)",
    ]


def test_the_tracker_command_does_not_need_the_loop() -> None:
    """``dyndlo-vision track`` reads videos through ``cameras``; the control loop is not its business."""
    imported = imported_modules(PACKAGE / "commands" / "track.py", "dyndlo_vision.commands.track")
    assert not any(room(name) in ("control", "learning", "cli") for name in imported), sorted(imported)


@pytest.mark.parametrize("path", sorted(BENCHMARKS.glob("*.py")), ids=lambda p: p.name)
def test_benchmarks_use_only_the_public_api(path: Path) -> None:
    """No command-line modules and no private names (``_x``) of the package."""
    imported = imported_modules(path, f"benchmarks.{path.stem}")
    assert not any(room(name) in ("commands", "cli") for name in imported), sorted(imported)
    private = [name for name in imported if any(part.startswith("_") for part in name.split(".")[1:])]
    assert private == [], private
