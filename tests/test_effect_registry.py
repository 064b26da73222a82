"""Adding an effect is one class in one file: registered with @register, it composes (`active + mine`), fits and
is found by the diagnosis; a name registered twice is an error naming both; rig/models has no import cycle, not even
through imports made for type checkers.

This file is itself an effects file: `rig diagnose REC --effects tests/test_effect_registry.py` loads the effect below
(load_effects runs the file; what it registers is its effects). The simulator's version of the same physics is
written here too, independently (it scales the projected light; the model multiplies the shot-noise variance).
"""

from __future__ import annotations

import json
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

import fakes.effects
from rig.models import Catalogue, Effect, EffectFileError, EffectStage, ModelData, Param, active, register
from rig.models.parts.component import registered_by

TILT = 0.8  # the simulated beam's fall-off down the image, per unit of y = (v - cy) / fy


@register
class VerticalFalloff(Effect):
    """The projector's beam points above the image centre, so its light falls off down the image: I ~ exp(-tilt y),
    y = (v - cy) / fy, and the shot-noise variance, 1 / I, grows as exp(tilt y)."""

    name = "vertical_falloff"
    stage = EffectStage.ILLUMINATION
    params = (Param("tilt", 0.0, -5.0, 5.0, "1", "fall-off of ln(light) per unit of y = (v - cy) / fy"),)
    signature = "the error grows from the top of the image to the bottom"
    explanation = "the projector's beam is tilted, so its light falls off down the image"

    def applicable(self, d):
        return None if d.projector_on.any() else "vertical_falloff needs the projector on"

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.where(d.projector_on, np.exp(p.tilt * d.y_norm), 1.0)


@fakes.effects.register
@dataclass
class SimulatedVerticalFalloff(fakes.effects.Effect):
    """The simulator's side: the pattern's photo-electrons times exp(-tilt yn), projector on only."""

    name: ClassVar[str] = "vertical_falloff"
    tilt: float = TILT

    def illumination(self, f) -> None:
        if f.projector_on:
            f.signal_e = f.signal_e * np.exp(-self.tilt * f.yn)


def mine() -> Effect:
    """The instance @register made of VerticalFalloff (this module registers no other)."""
    (effect,) = registered_by(__name__)
    return effect


@pytest.fixture(scope="module")
def tilted_beam(tmp_path_factory) -> Path:
    """A perpendicular run of the fake camera (64x36 px, 5 stops, 30 frames) whose beam falls off down the image."""
    from simrig import record_perpendicular

    path, _, _ = record_perpendicular(tmp_path_factory.mktemp("beam") / "beam.h5", width=64, frames=30, seed=4,
                                      stops_m=[0.5, 1.0, 1.5, 2.0, 2.5], effects=f"vertical_falloff(tilt={TILT})")
    return path


def test_an_effect_defined_here_composes_and_fits_recovering_its_parameter(tilted_beam):
    model = active + mine()
    assert model.name == "active+vertical_falloff" and [n for n, _ in model.free()] == ["k", "vertical_falloff.tilt"]
    assert Catalogue.builtin().with_effects([mine()], __file__).parse("active+vertical_falloff") == model
    f = model.fit(ModelData.from_recording(tilted_beam))
    tilt, se = f.values["vertical_falloff.tilt"], f.errors["vertical_falloff.tilt"]
    assert 0 < se < 0.05 * TILT
    assert abs(tilt - TILT) < 3 * se, (tilt, se)  # 3 standard errors: the chance of a miss is 0.3 %


@pytest.mark.slow
def test_the_diagnosis_finds_it_from_the_effects_flag(tilted_beam, tmp_path, capsys):
    from rig.cli import main

    assert main(["diagnose", str(tilted_beam), "--effects", __file__, "--out", str(tmp_path / "d"), "--jobs", "1",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    part = doc["diagnosis"]
    assert part["candidates"][0]["effect"] == "vertical_falloff" and part["candidates"][0]["significant"]
    assert part["added"][:1] == ["vertical_falloff"], part["summary"]
    assert part["summary"].startswith("Most likely missing: vertical_falloff.")


def test_a_name_registered_twice_in_one_file_is_an_error_naming_both(tmp_path, small_recording, capsys):
    from rig.cli import main

    twice = tmp_path / "twice.py"
    twice.write_text(textwrap.dedent('''
        from rig.models import Effect, EffectStage, register

        @register
        class First(Effect):
            name = "glare"
            stage = EffectStage.ILLUMINATION

        @register
        class Second(Effect):
            name = "glare"
            stage = EffectStage.ILLUMINATION
    '''))
    assert main(["fit", str(small_recording), "--effects", str(twice)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'glare' registered twice" in err, err
    assert "First (" in err and "twice.py:4)" in err and "Second (" in err and "twice.py:9)" in err, err  # the @register lines


def test_registering_a_built_in_name_again_is_an_error_naming_both():
    namespace = {"__name__": "rig.models.another", "Effect": Effect, "EffectStage": EffectStage, "register": register}
    with pytest.raises(EffectFileError, match=r"'noise_floor' registered twice: by NoiseFloor "
                                              r"\(rig/models/effects/builtin/noise_floor\.py:\d+\) and by Floor2"):
        exec("@register\nclass Floor2(Effect):\n    name = 'noise_floor'\n    stage = EffectStage.DISPARITY\n",
             namespace)


def test_every_built_in_effect_is_one_module_named_for_it_and_found_by_name():
    import rig.models

    assert list(rig.models.EFFECTS) == ["noise_floor", "read_noise", "ambient", "slant_range", "incidence", "outliers",
                                        "quantization", "drift", "censoring", "measured_light"]  # by position: seeds keep theirs
    for name, e in rig.models.EFFECTS.items():
        assert getattr(rig.models, name) is e and getattr(rig.models, type(e).__name__) is type(e)
        assert type(e).__module__ == f"rig.models.effects.builtin.{name}"
        assert e.defined_at.startswith(f"rig/models/effects/builtin/{name}.py:")
        assert e.twin is None or e.twin in fakes.effects.EFFECTS, (name, e.twin)  # the simulator's own effect
    with pytest.raises(AttributeError):
        rig.models.no_such_effect  # noqa: B018


#: docs/architecture.md's example: the projector's beam falling as cos^n off axis, which the catalogue lacks and the
#: simulator has (fakes/effects.py's beam_falloff, the blind test's "not in the catalogue" scenario until now)
BEAM_MODULE = '''
"""`beam_cos`: the projector's beam falls off as cos^n of the off-axis angle."""

import numpy as np

from rig.models import Effect, EffectStage, Param, register
from rig.models.parts.tangents import plus, scale


@register
class BeamCos(Effect):
    """The projector's beam falls off as cos^n of the off-axis angle: the shot-noise variance grows as
    (1 + rho^2)^(n / 2)."""

    name = "beam_cos"
    stage = EffectStage.ILLUMINATION
    params = (Param("n", 2.0, 0.0, 12.0, "1", "exponent of the beam's cos^n fall-off"),)
    signature = "the error grows towards the image corners faster than slant range explains"
    explanation = "the projector's beam is brightest on its axis and falls off as cos^n away from it"
    twin = "beam_falloff"
    position = 10

    def scenario(self, rng):
        return {"n": rng.uniform(3.0, 6.0)}

    def applicable(self, d):
        return None if d.projector_on.any() else "beam_cos needs the projector on"

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.where(d.projector_on, (1.0 + d.rho2) ** (0.5 * p.n), 1.0)

    def apply_tangent(self, pred, p, d, t):
        factor = np.where(d.projector_on, (1.0 + d.rho2) ** (0.5 * p.n), 1.0)
        dfactor = factor * np.where(d.projector_on, 0.5 * np.log1p(d.rho2), 0.0)
        own = [(i, pred.illum * dfactor)] if (i := t.row(self, "n")) is not None else []
        t.illum = plus(scale(t.illum, factor), t.seeded(own))
        pred.illum = pred.illum * factor
'''

#: run in a fresh interpreter: the folder holding the new module joins the built-in effects' package, as a module
#: saved in rig/models/effects/builtin/ does; then everything that should know about it is asked
ADD_CHECK = '''
import json, sys
import numpy as np
import rig.models.effects.builtin as builtin
builtin.__path__.append(sys.argv[1])
found = builtin.discover()
from rig.models import EFFECTS, Catalogue, ModelData, parse_model
from rig.models.fitting.likelihood import model_loglik_gradient
from rig.simulation.scenarios import CHOICES, NOT_IN_CATALOGUE, expected, hidden_scenario, record_scenario
from rig.diagnosis.candidates import applicable_candidates
e = EFFECTS["beam_cos"]
sc = hidden_scenario(5, "beam_falloff", width=48, frames=30)
path = record_scenario(sc, sys.argv[1] + "/beam.h5")
d = ModelData.from_recording(path)
model = Catalogue.default().parse("active+beam_cos")
fit = model.fit(d)
values = dict(fit.values, **{"beam_cos.n": fit.values["beam_cos.n"] + 3 * fit.errors["beam_cos.n"]})  # off the top
ll, grad = model_loglik_gradient(model, values, d, ["k", "beam_cos.n"])
h = 1e-4 * values["beam_cos.n"]
up, down = dict(values, **{"beam_cos.n": values["beam_cos.n"] + h}), dict(values, **{"beam_cos.n": values["beam_cos.n"] - h})
print(json.dumps({"found": found, "order": list(EFFECTS), "module": type(e).__module__,
                  "in_choices": "beam_falloff" in CHOICES, "not_in_catalogue": sorted(NOT_IN_CATALOGUE),
                  "expected": expected("beam_falloff").named, "hidden_n": sc.params["n"],
                  "n": fit.values["beam_cos.n"], "se": fit.errors["beam_cos.n"],
                  "grad": grad[1], "diff": (model.loglik(up, d) - model.loglik(down, d)) / (2 * h),
                  "candidate": "beam_cos" in [c.name for c in applicable_candidates(parse_model("active"), d)]}))
'''


def test_adding_an_effect_is_one_module_that_everything_finds(tmp_path):
    """docs/architecture.md's 'add an effect': one module, found by the registry. Here it is saved in a folder
    joined to the built-in effects' package, in a fresh interpreter (so the catalogue of this test session is left
    as it is): the effect takes its place in the catalogue, fits with its derivative, is a candidate of the
    diagnosis, and the blind test now hides its twin (the simulator's beam_falloff) and expects it by name."""
    import subprocess
    import sys

    (tmp_path / "beam_cos.py").write_text(BEAM_MODULE)
    r = subprocess.run([sys.executable, "-c", ADD_CHECK, str(tmp_path)], capture_output=True, text=True, timeout=300,
                       cwd=Path(__file__).resolve().parents[1])
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert "beam_cos" in got["found"] and got["order"][-1] == "beam_cos" and got["order"][0] == "noise_floor"
    assert got["module"] == "rig.models.effects.builtin.beam_cos"
    assert got["in_choices"] and "beam_falloff" not in got["not_in_catalogue"]
    assert got["expected"] == ["beam_cos"] and got["candidate"]
    # the fit recovers the hidden exponent: cos^n of the off-axis angle is (1 + rho^2)^(-n/2) exactly
    assert abs(got["n"] - got["hidden_n"]) < 4 * got["se"], got
    # the analytic derivative, 3 standard errors off the maximum (where it is about -3 / se nats per unit), against
    # central differences, whose own error (h^2 / 6 times the third derivative, h = 1e-4 n) is far below 1e-4 of it
    assert abs(got["diff"]) * got["se"] > 1.0 and abs(got["grad"] - got["diff"]) < 1e-4 * abs(got["diff"]), got


def test_the_models_package_has_no_import_cycle_even_for_type_checkers():
    """tests/test_layers.py leaves out imports under `if TYPE_CHECKING:`; here they count too, inside rig.models."""
    import grimp

    g = grimp.build_graph("rig", exclude_type_checking_imports=False, cache_dir=None)
    models = sorted(m for m in g.modules if m.startswith("rig.models."))
    cycles = [(m, i) for m in models for i in g.find_modules_directly_imported_by(m)
              if i.startswith("rig.models.") and g.find_shortest_chain(importer=i, imported=m)]
    assert len(models) > 25 and not cycles, cycles
