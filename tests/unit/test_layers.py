"""The layers of the tree, enforced by import-linter's contracts (pyproject.toml).

The repository keeps ``common/``, ``services/``, ``sim/`` and ``configs/`` at the top and
installs them inside the ``quadmanip`` package (setup.py), so no folder on disk holds the
whole package. import-linter reads packages from disk: the test lays the Python files out
as they are installed, in a temporary folder, and runs ``lint-imports`` there.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[2]
MAPPED = ("common", "services", "sim", "hardware", "configs")  # setup.py's TOP_LEVEL
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


def installed_layout(dest: Path) -> Path:
    """Copy the package's Python files to ``dest/quadmanip`` as they are installed."""
    keep_py = shutil.ignore_patterns("__pycache__", "*.pyc", "*.xml", "*.stl", "*.obj", "*.png")
    shutil.copytree(ROOT / "quadmanip", dest / "quadmanip", ignore=keep_py)
    for folder in MAPPED:
        shutil.copytree(ROOT / folder, dest / "quadmanip" / folder, ignore=keep_py)
    return dest


def lint_imports(tree: Path) -> subprocess.CompletedProcess[str]:
    # lint-imports puts its working directory first on the path: run it inside the copy.
    return subprocess.run(
        [str(LINT_IMPORTS), "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
        cwd=tree,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_import_contracts_are_kept(tmp_path: Path) -> None:
    result = lint_imports(installed_layout(tmp_path))
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout and "BROKEN" not in result.stdout


@pytest.mark.parametrize(
    ("module", "line", "contract"),
    [
        ("services/locomotion/gait.py", "import zenoh", "Algorithm modules"),
        ("services/manipulation/grasp.py", "import quadmanip.sim.engine", "no sim"),
        ("services/viz/sinks.py", "import quadmanip.services.locomotion.gait", "no other service"),
        ("common/config.py", "import quadmanip.launcher", "common imports no"),
        ("sim/judge.py", "import quadmanip.testbench.stack", "simulator imports no"),
    ],
)
def test_a_violation_breaks_its_contract(
    tmp_path: Path, module: str, line: str, contract: str
) -> None:
    tree = installed_layout(tmp_path)
    path = tree / "quadmanip" / module
    path.write_text(path.read_text() + f"\n{line}  # a deliberate violation\n")
    result = lint_imports(tree)
    assert result.returncode != 0
    broken = [ln for ln in result.stdout.splitlines() if ln.endswith("BROKEN") or "BROKEN (" in ln]
    assert any(contract in ln for ln in broken), result.stdout[-3000:]
