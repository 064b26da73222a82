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
    """Stricter than the contracts: no module reaches itself through imports, parents and children included, and
    imports under `if TYPE_CHECKING:` counted too (a circle a type checker follows is a circle). grimp is
    import-linter's graph builder."""
    import grimp

    g = grimp.build_graph(*PACKAGES, exclude_type_checking_imports=False)
    cycles = []
    for m in sorted(g.modules):
        for imported in g.find_modules_directly_imported_by(m):
            if g.find_shortest_chain(importer=imported, imported=m):
                cycles.append((m, imported))
    assert len(g.modules) > 60
    assert not cycles, f"import cycles through these edges: {cycles[:10]}"


#: imports made inside functions on purpose, each for a start-up cost or an optional dependency (below the command
#: line and its TUI entry, whose commands import what they use when they run): module -> why. The costs are
#: `python -X importtime` after numpy, scipy and h5py, the least of five, on the 2-core AMD EPYC of 2026-11-28
LAZY = {
    "scipy.optimize": "410 ms, and only iterative fits need it (the power law's closed form does not)",
    "scipy.ndimage": "56 ms, for two simulated effects only",
    "scipy.stats": "1.5 s, for the warm-up's fit only (a run that asks for one)",
    "matplotlib": "886 ms with pyplot, for plots only", "matplotlib.pyplot": "idem", "matplotlib.backend_bases": "idem",
    "matplotlib.text": "idem (rig.reports.output_file also writes pages without plots)",
    "distributed": "the optional cluster extra", "depthai": "an optional SDK", "pyrealsense2": "an optional SDK",
    "rosbags.highlevel": "161 ms, bags only", "rosbags.typesys": "idem", "rosbags.interfaces": "idem",
    "rosbags.rosbag1": "59 ms, ROS 1 bags only", "PIL": "30 ms, PNG folders only", "serial.tools": "listing ports only",
    "tifffile": "12 ms, sigma maps only",
    "numba": "drivers/compiled.py: 535 ms the drivers do not pay unless they compile",
    "importlib.metadata": "24 ms on every command, for a version string", "tomllib": "a source tree's version only",
}
#: modules that import lazily for the start of the program: the command line's, and the TUI's entry
ENTRY = ("rig/cli/", "rig/tui/__init__.py", "rig/tui/launch.py")


def test_imports_inside_functions_are_the_listed_lazy_ones():
    """Below the command line an import sits at the top of its module, where the graph and the contracts see it,
    unless it is one of LAZY (a measured start-up cost, or an optional dependency)."""
    import ast

    found = []
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*.py"):
            rel = str(p.relative_to(ROOT))
            if rel.startswith(ENTRY):
                continue
            for fn in ast.walk(ast.parse(p.read_text())):
                if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    for node in ast.walk(fn):
                        if isinstance(node, ast.ImportFrom):
                            mod = "." * node.level + (node.module or "")
                        elif isinstance(node, ast.Import):
                            mod = node.names[0].name
                        else:
                            continue
                        if mod not in LAZY:
                            found.append(f"{rel}:{node.lineno} {mod}")
    assert not found, f"move these imports to the top of their modules, or say why in LAZY: {found}"
