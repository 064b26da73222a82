"""The effects a model can be built from: the built-in ones, installed plugins' and the user's files.

    cat = Catalogue.default().with_file("my_effects.py")
    model = cat.parse("active+slant_range+beam_falloff")
    diagnose(data, catalogue=cat)          # ranks beam_falloff with the others

Installed packages add effects under the entry-point group `rig.effects` (an `Effect`, or a
list of them); `Catalogue.default()` includes them. Empirical terms (`empirical(radius)`,
rig.models.effects.empirical) parse in every catalogue but are not candidates: the diagnosis fits them
only when nothing physical explains what remains.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path

from .bases import BASES
from .parts.component import Effect, describe, registered_by
from .composition import Model
from .effects.builtin import EFFECTS
from .effects.empirical import empirical, is_empirical
from .effects.user_effects import EffectFileError, load_effects

ENTRY_POINT_GROUP = "rig.effects"


@dataclass(frozen=True)
class Catalogue:
    """Effects by name, with where each came from ("built-in", a file, or an entry point)."""

    effects: dict[str, Effect] = field(default_factory=lambda: dict(EFFECTS))
    sources: dict[str, str] = field(default_factory=lambda: {n: "built-in" for n in EFFECTS})

    @classmethod
    def builtin(cls) -> "Catalogue":
        return cls()

    @classmethod
    def default(cls) -> "Catalogue":
        """The built-in effects and those of installed plugins."""
        cat = cls()
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            try:
                loaded = ep.load()
            except Exception as e:
                raise EffectFileError(f"the effect plugin {ep.name} ({ep.value}) failed to load ({type(e).__name__}: {e}); "
                                      "reinstall or remove the package that provides it") from None
            cat = cat.with_effects(_as_effects(loaded), f"entry point {ep.name}")
        return cat

    def with_effects(self, effects: list[Effect], source: str) -> "Catalogue":
        """This catalogue and `effects`; a name taken already is a one-line error."""
        names, sources = dict(self.effects), dict(self.sources)
        for e in effects:
            if e.name in names and names[e.name] is not e:
                raise EffectFileError(f"effect {e.name} from {source}, {describe(e)}, has the name of the "
                                      f"{sources[e.name]} effect {e.name}, {describe(names[e.name])}; rename it")
            names[e.name], sources[e.name] = e, source
        return Catalogue(names, sources)

    def with_file(self, path: str | Path) -> "Catalogue":
        return self.with_effects(load_effects(path), str(path))

    def candidates(self) -> list[Effect]:
        """The effects the diagnosis tries, in catalogue order: all but the empirical terms and those a model must
        name (`Effect.diagnosed` False: `measured_light`)."""
        return [e for e in self.effects.values() if not is_empirical(e) and getattr(e, "diagnosed", True)]

    def user_effects(self) -> list[Effect]:
        return [e for n, e in self.effects.items() if self.sources[n] != "built-in"]

    def parse(self, text: str) -> Model:
        """'active+slant_range+noise_floor' (or '...+empirical(radius)') -> Model."""
        parts = text.replace(" ", "").split("+")
        if not parts[0] or parts[0] not in BASES:
            raise ValueError(f"model {text!r} must start with a base model ({', '.join(BASES)}), e.g. active+slant_range")
        if "" in parts[1:]:
            raise ValueError(f"model {text!r} has a '+' with no effect after it; name the effect "
                             f"({parts[0]}+noise_floor) or drop the '+'")
        twice = sorted({name for name in parts[1:] if parts[1:].count(name) > 1})
        if twice:
            raise ValueError(f"model {text!r} names {', '.join(twice)} twice; name each effect once")
        m = Model(BASES[parts[0]])
        for name in parts[1:]:
            if name.startswith("empirical(") and name.endswith(")"):
                m = m + empirical(name[len("empirical("):-1])
                continue
            if name not in self.effects:
                known = ", ".join(self.effects)
                raise ValueError(f"unknown effect {name!r} in model {text!r}; effects: {known}, or empirical(COVARIATE)"
                                 + ("" if self.user_effects() else "; load your own with --effects FILE.py"))
            m = m + self.effects[name]
        return m


def _as_effects(loaded: object) -> list[Effect]:
    """What an entry point names, as effects: an effect, an effect's class (the instance @register made of it), or a
    list of them."""
    out = []
    for x in loaded if isinstance(loaded, (list, tuple)) else [loaded]:
        if isinstance(x, type) and issubclass(x, Effect):
            x = next((e for e in registered_by(x.__module__) if type(e) is x), None) or x()
        if isinstance(x, Effect):
            out.append(x)
    return out
