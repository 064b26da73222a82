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
    assert "5 kept, 0 broken" in r.stdout


def test_no_module_is_a_dumping_ground():
    sizes = {str(p.relative_to(ROOT)): len(p.read_text().splitlines())
             for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    assert len(sizes) > 60
    too_big = {p: n for p, n in sizes.items() if n > MAX_MODULE_LINES}
    assert not too_big, f"split these modules by concept (docs/architecture.md): {too_big}"


def test_the_module_import_graph_has_no_cycle():
    """Stricter than the contracts: no module reaches itself through imports, parents and children included
    (imports under `if TYPE_CHECKING:` do not run and are left out). grimp is import-linter's graph builder."""
    import grimp

    g = grimp.build_graph(*PACKAGES, exclude_type_checking_imports=True)
    cycles = []
    for m in sorted(g.modules):
        for imported in g.find_modules_directly_imported_by(m):
            if g.find_shortest_chain(importer=imported, imported=m):
                cycles.append((m, imported))
    assert len(g.modules) > 60
    assert not cycles, f"import cycles through these edges: {cycles[:10]}"
