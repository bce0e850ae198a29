"""The layer order holds: import-linter's contracts (pyproject.toml) and no project import hidden
inside a function, the usual way an import cycle is dodged."""

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("groundstation", "drivers", "web", "sim_bridge")


@pytest.mark.skipif(
    shutil.which("lint-imports", path=str(Path(sys.executable).parent)) is None,
    reason="import-linter is not installed (make test installs it)",
)
def test_the_layer_contracts_are_kept():
    exe = Path(sys.executable).parent / "lint-imports"
    r = subprocess.run([str(exe)], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "BROKEN" not in r.stdout


def test_no_module_imports_the_project_inside_a_function():
    found = []
    for pkg in PACKAGES:
        for path in (REPO / pkg).rglob("*.py"):
            tree = ast.parse(path.read_text(), str(path))
            for fn in ast.walk(tree):
                if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                for node in ast.walk(fn):
                    if isinstance(node, ast.ImportFrom):
                        mod = node.module or ""
                        if node.level or mod.split(".")[0] in PACKAGES:
                            found.append(f"{path.relative_to(REPO)}:{node.lineno} {ast.unparse(node)}")
                    elif isinstance(node, ast.Import):
                        found += [
                            f"{path.relative_to(REPO)}:{node.lineno} {ast.unparse(node)}"
                            for a in node.names
                            if a.name.split(".")[0] in PACKAGES
                        ]
    assert not found, "\n".join(found)
