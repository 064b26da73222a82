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
    with pytest.raises(EffectFileError, match=r"'noise_floor' registered twice: by NoiseFloor \(rig/models/effects/builtin\.py:\d+\) "
                                              r"and by Floor2"):
        exec("@register\nclass Floor2(Effect):\n    name = 'noise_floor'\n    stage = EffectStage.DISPARITY\n",
             namespace)


def test_every_built_in_effect_is_found_by_name_without_an_export_list():
    import rig.models
    import rig.models.effects.builtin

    for name, e in rig.models.EFFECTS.items():
        assert getattr(rig.models, name) is e and getattr(rig.models.effects.builtin, name) is e
        assert getattr(rig.models, type(e).__name__) is type(e)
        assert e.defined_at.startswith("rig/models/effects/builtin.py:")
    with pytest.raises(AttributeError):
        rig.models.no_such_effect  # noqa: B018


def test_the_models_package_has_no_import_cycle_even_for_type_checkers():
    """tests/test_layers.py leaves out imports under `if TYPE_CHECKING:`; here they count too, inside rig.models."""
    import grimp

    g = grimp.build_graph("rig", exclude_type_checking_imports=False, cache_dir=None)
    models = sorted(m for m in g.modules if m.startswith("rig.models."))
    cycles = [(m, i) for m in models for i in g.find_modules_directly_imported_by(m)
              if i.startswith("rig.models.") and g.find_shortest_chain(importer=i, imported=m)]
    assert len(models) > 25 and not cycles, cycles
