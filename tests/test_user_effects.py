"""Effects written by the user: loaded from a file or an entry point, they fit exactly like built-in ones,
and every mistake in the file is one line naming the file and the fix."""

import textwrap

import numpy as np
import pytest

from rig.cli import main
from rig.models import Catalogue, ModelData
from rig.models.catalogue import ENTRY_POINT_GROUP
from rig.models.effects.user_effects import EffectFileError, load_effects
from rig.simulation.scenarios import hidden_scenario, record_scenario

#: the built-in noise floor (rig/models/effects/builtin/noise_floor.py), written again as a user would
MY_FLOOR = '''
from rig.models import Param, TermEffect, register

@register
class MyFloor(TermEffect):
    """A disparity noise floor, written by hand."""

    name = "my_floor"
    stage = "disparity"
    params = (Param("sigma_px", 0.01, 0.0, 5.0, "px", "disparity noise floor"),)
    signature = "the error exceeds k Z^lambda most at short range"

    def term(self, c, sigma_px):
        return sigma_px ** 2 + 0 * c.z_m
'''


@pytest.fixture(scope="module")
def floor_recording(tmp_path_factory):
    return record_scenario(hidden_scenario(21, "noise_floor", width=60, frames=40),
                           tmp_path_factory.mktemp("u") / "floor.h5")


def write(tmp_path, text, name="fx.py"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_a_user_effect_fits_exactly_like_the_built_in_it_copies(tmp_path, floor_recording):
    cat = Catalogue.default().with_file(write(tmp_path, MY_FLOOR))
    d = ModelData.from_recording(floor_recording)
    built_in = cat.parse("active+noise_floor").fit(d)
    mine = cat.parse("active+my_floor").fit(d)
    assert mine.loglik == pytest.approx(built_in.loglik, rel=1e-9, abs=1e-6)
    a, b = built_in.values["noise_floor.sigma_px"], mine.values["my_floor.sigma_px"]
    assert abs(a - b) < 0.01 * built_in.errors["noise_floor.sigma_px"]
    assert "my_floor.sigma_px" in mine.report() and "px" in mine.report()


@pytest.mark.slow
def test_the_effects_flag_on_fit_and_compare(tmp_path, floor_recording, capsys):
    fx = write(tmp_path, MY_FLOOR)
    assert main(["fit", str(floor_recording), "--model", "active+my_floor", "--effects", str(fx)]) == 0
    assert "my_floor.sigma_px" in capsys.readouterr().out
    assert main(["compare", str(floor_recording), "--models", "active,active+my_floor", "--effects", str(fx),
                 "--no-held-out"]) == 0
    assert "active+my_floor" in capsys.readouterr().out


BAD_FILES = [
    ("missing.py", None, "does not exist"),
    ("syntax.py", "def f(:\n", "syntax error"),
    ("none.py", "x = 1\n", "defines no effect"),
    ("stage.py", MY_FLOOR.replace('stage = "disparity"', 'stage = "optics"'), "is not one of"),
    ("bounds.py", MY_FLOOR.replace("0.01, 0.0, 5.0", "9.0, 0.0, 5.0"), "outside its bounds"),
    ("clash.py", MY_FLOOR.replace('name = "my_floor"', 'name = "noise_floor"'), "has the name of the built-in"),
    ("raises.py", "from rig.models import TermEffect\nraise RuntimeError('boom')\n", "running it failed"),
    ("no_term.py", MY_FLOOR.replace("def term(self", "def terms(self"), "write its term"),
    ("decorator.py", "from rig.models import effect\n", "running it failed"),
]


@pytest.mark.parametrize("name,text,message", BAD_FILES)
def test_a_bad_effects_file_is_one_line(tmp_path, floor_recording, capsys, name, text, message):
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    assert main(["fit", str(floor_recording), "--effects", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and name in err and "Traceback" not in err, err


def test_an_effect_that_returns_nonsense_is_named(tmp_path, floor_recording, capsys):
    path = write(tmp_path, MY_FLOOR.replace("return sigma_px ** 2 + 0 * c.z_m", "return -c.z_m"))
    assert main(["fit", str(floor_recording), "--model", "active+my_floor", "--effects", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "my_floor" in err and "negative" in err, err


def test_an_installed_package_publishes_effects_by_entry_point(tmp_path, monkeypatch):
    pkg = tmp_path / "site"
    (pkg / "labfx").mkdir(parents=True)
    (pkg / "labfx" / "__init__.py").write_text(MY_FLOOR)
    info = pkg / "labfx-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: labfx\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nmy_floor = labfx:MyFloor\n")
    monkeypatch.syspath_prepend(str(pkg))
    cat = Catalogue.default()
    assert "my_floor" in cat.effects and cat.sources["my_floor"] == "entry point my_floor"
    assert cat.parse("active+my_floor").name == "active+my_floor"


def test_load_effects_finds_every_effect_in_a_file(tmp_path):
    two = MY_FLOOR + MY_FLOOR.replace("my_floor", "other_floor").replace("MyFloor", "OtherFloor")
    found = load_effects(write(tmp_path, two))
    assert sorted(e.name for e in found) == ["my_floor", "other_floor"]
    with pytest.raises(EffectFileError, match="not a unique identifier"):
        load_effects(write(tmp_path, MY_FLOOR.replace('Param("sigma_px"', 'Param("sigma px"'), "b.py"))
    assert np.isfinite(found[0].params[0].value)
