"""rig and rig.sim re-export what other packages use, lazily; no private names cross modules."""

import ast
import subprocess
import sys
from pathlib import Path

import rig
import rig.sim

ROOT = Path(__file__).resolve().parents[2]


def test_names_resolve_and_import_rig_stays_light():
    for module in (rig, rig.sim):
        for name in module.__all__:
            assert getattr(module, name) is not None, name
    code = "import rig, rig.sim, sys; print('serial' in sys.modules, 'usb' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT).stdout
    assert out.split() == ["False", "False"]


def test_no_module_of_rig_imports_a_private_name():
    offenders = []
    for path in (ROOT / "rig").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                offenders += [f"{path.relative_to(ROOT)}: {a.name}" for a in node.names
                              if a.name.startswith("_") and a.name != "__version__"]
    assert offenders == []
