"""Tests of the dyndlo_vision.tracking package's lazy exports."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import dyndlo_vision.tracking as tracking


def test_every_export_resolves_to_its_submodule() -> None:
    for name, module in tracking._EXPORTS.items():
        submodule = importlib.import_module(f"dyndlo_vision.tracking.{module}")
        assert getattr(tracking, name) is getattr(submodule, name)
    assert sorted(tracking.__all__) == sorted(tracking._EXPORTS)


def test_type_checking_imports_match_the_exports() -> None:
    tree = ast.parse(Path(tracking.__file__).read_text(encoding="utf-8"))
    block = next(n for n in tree.body if isinstance(n, ast.If) and ast.unparse(n.test) == "TYPE_CHECKING")
    imports = [node for node in block.body if isinstance(node, ast.ImportFrom)]
    imported = {alias.name: node.module for node in imports for alias in node.names}
    assert imported == tracking._EXPORTS


def test_importing_the_parameters_loads_nothing_heavy() -> None:
    """``dyndlo-vision track`` shows the filter defaults in its --help: that must not load SciPy, filterpy
    or OpenCV into the start-up of every command."""
    code = (
        "import sys; import dyndlo_vision.tracking.params; "
        "print(sorted(m for m in ('cv2', 'filterpy', 'scipy.stats') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
