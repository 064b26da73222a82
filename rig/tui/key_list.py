"""The TUI's keys as its bindings say, for the help screen (`?`): made from the classes' BINDINGS, never a hand list,
so the help cannot drift from what the keys do."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from textual.binding import Binding, BindingsMap
from textual.keys import format_key


@dataclass(frozen=True)
class KeyRow:
    group: str  # where the keys work: "everywhere", a screen, a widget
    keys: tuple[str, ...]  # as the keyboard says them: "ctrl+q", "?", "esc"
    does: str
    letters: frozenset[str] = frozenset()  # those of `keys` that are off while a text field has the focus (it takes them)

    def keys_text(self) -> str:
        """The keys, those a text field takes marked with a star: "f1, 1*"."""
        return ", ".join(k + "*" * (k in self.letters) for k in self.keys)


def bindings_of(cls: type) -> list[Binding]:
    """The bindings `cls` declares itself (its BINDINGS), one key each, as Textual reads them (`BindingsMap`); those
    without a description are left out. (Textual's own widgets' keys, arrows and the like, are theirs to list.)"""
    return [b for declared in cls.__dict__.get("BINDINGS", []) for _, b in BindingsMap([declared])  # (in their order)
            if b.description and not b.system]


def action_name(binding: Binding) -> str:
    """The action without its arguments: show_tab('run') -> show_tab."""
    return binding.action.split("(")[0]


def key_rows(bound: Iterable[tuple[str, Binding]], letters: frozenset[str] = frozenset()) -> list[KeyRow]:
    """One row per thing keys do, from (group, binding) pairs, grouped in the order the groups first come: the keys of
    one description in a group share a row (f1 and 1: Devices screen), and so do the descriptions of the same keys
    (p: Pause / Continue). Keys of actions in `letters` are off while a text field has the focus."""
    keys_of: dict[tuple[str, str], list[str]] = {}
    off: set[tuple[str, str]] = set()
    for group, b in bound:
        keys = keys_of.setdefault((group, b.description), [])
        key = format_key(b.key)
        if key not in keys:
            keys.append(key)
        if action_name(b) in letters:
            off.add((group, key))
    does_of: dict[tuple[str, tuple[str, ...]], list[str]] = {}
    for (group, does), keys in keys_of.items():
        does_of.setdefault((group, tuple(keys)), []).append(does)
    groups = list(dict.fromkeys(group for group, _ in does_of))
    rows = [KeyRow(group, keys, " / ".join(does), frozenset(k for k in keys if (group, k) in off))
            for (group, keys), does in does_of.items()]
    return sorted(rows, key=lambda r: groups.index(r.group))  # (stable: in each group, the bindings' order)
