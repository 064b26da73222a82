"""The layout stays readable: imports go one way, no import cycles, no module grows past ~450 lines."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rig", "drivers", "protocols", "fakes")
MAX_MODULE_LINES = 450


def test_import_contracts_hold():
    """lint-imports (import-linter) checks the contracts in pyproject.toml: rig -> (protocols | fakes) -> drivers,
    the layers inside rig, and no cycles between the modules of any package."""
    lint = Path(sys.executable).parent / "lint-imports"
    assert lint.exists(), "install the test extra (python3 dev.py test does) so lint-imports exists"
    r = subprocess.run([str(lint), "--no-cache"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "3 kept, 0 broken" in r.stdout


def test_no_module_is_a_dumping_ground():
    sizes = {str(p.relative_to(ROOT)): len(p.read_text().splitlines())
             for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    assert len(sizes) > 60
    too_big = {p: n for p, n in sizes.items() if n > MAX_MODULE_LINES}
    assert not too_big, f"split these modules by concept (docs/architecture.md): {too_big}"
