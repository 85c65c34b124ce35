"""The package boundary: physics never imports the renderer, the renderer never imports physics.
Read from the source (every import statement, at any depth), so a lazy import counts too."""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# the application layer: commands that simulate and then draw frames or plots
APP_MODULES = {"__main__", "cli", "runner", "reports", "bench", "cluster", "sweep"}


def imported_packages(path: Path) -> set:
    """Top-level names of every module `path` imports (relative imports count as its own)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_physics_modules_do_not_import_render():
    physics = [p for p in sorted((ROOT / "taichi_hair").rglob("*.py")) if p.stem not in APP_MODULES]
    assert len(physics) > 20
    offenders = [p.name for p in physics if "render" in imported_packages(p)]
    assert offenders == []


def test_render_does_not_import_taichi_hair():
    modules = sorted((ROOT / "render").rglob("*.py"))
    assert len(modules) > 5
    offenders = [p.name for p in modules if "taichi_hair" in imported_packages(p)]
    assert offenders == []


def test_import_boundary_detects_an_offender(tmp_path):
    """The check itself can fail: a module with a lazy render import is caught."""
    module = tmp_path / "rod_like.py"
    module.write_text("def f():\n    from render.plot import loglog\n    return loglog\n")
    assert "render" in imported_packages(module)


def test_importing_the_package_loads_no_renderer():
    code = "import sys, taichi_hair; print('render' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "False"
