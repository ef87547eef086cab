"""Model specifications (``specs/*.toml``, contract section 3): a kind and a list of effects."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from .effect import REGISTRY, Effect, toml_value
from .errors import InputError, parse_toml
from .files import read_text_input


@dataclass
class Spec:
    """A parsed model specification.

    Attributes
    ----------
    kind : str
        ``"encoder"`` or ``"robot"``.
    effects : list of Effect
        In the order of the spec; the waterfall of diagnosis adds them in this order.
    model : dict
        The ``[model]`` table (options of the fit beyond ``kind``).
    select : dict
        The ``[select]`` table (order selection thresholds; encoder only).
    path : str or None
    text : str or None
        The spec's text as parsed (to locate a line in messages, also where the file is not
        at hand, e.g. on a Dask worker).
    """

    kind: str
    effects: list[Effect]
    model: dict = field(default_factory=dict)
    select: dict = field(default_factory=dict)
    path: str | None = None
    text: str | None = field(default=None, repr=False, compare=False)

    def located(self, message: str, pattern: str) -> InputError:
        """An InputError in this spec at the first line matching ``pattern`` (when known)."""
        line, col = _locate(self.text, pattern) if self.text else (None, None)
        return InputError(self.path or "<spec>", message, line, col)

    def require_kind(self, kind: str, data: str) -> None:
        """Refuse (at the spec's ``kind`` line) a spec that is not for a ``kind`` campaign ``data``."""
        if self.kind != kind:
            def a(word):
                return "an" if word[0] in "aeiou" else "a"

            raise self.located(f"the spec is for {a(self.kind)} {self.kind} model but {data} is {a(kind)} {kind} "
                               "campaign", r"^\s*kind\s*=")

    def effect(self, name):
        for e in self.effects:
            if e.name == name:
                return e
        return None

    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    def with_effect(self, effect: Effect) -> "Spec":
        return Spec(self.kind, [*self.effects, effect], dict(self.model), dict(self.select), self.path)

    def to_toml(self) -> str:
        lines = ["[model]", f'kind = "{self.kind}"']
        for key, value in self.model.items():
            if key != "kind":
                lines.append(f"{key} = {toml_value(value)}")
        if self.select:
            lines += ["", "[select]"] + [f"{k} = {toml_value(v)}" for k, v in self.select.items()]
        for e in self.effects:
            lines += ["", e.spec_lines()]
        return "\n".join(lines) + "\n"


def _locate(text: str, pattern: str) -> tuple[int | None, int | None]:
    match = re.search(pattern, text, flags=re.MULTILINE)
    if not match:
        return None, None
    line = text.count("\n", 0, match.start()) + 1
    col = match.start() - (text.rfind("\n", 0, match.start()) + 1) + 1
    return line, col


def parse_spec(text: str, path: str = "<spec>") -> Spec:
    doc = parse_toml(text, path)

    model = doc.get("model")
    if not isinstance(model, dict) or "kind" not in model:
        raise InputError(path, "missing [model] table with kind = \"encoder\" or \"robot\"", 1, 1)
    kind = model["kind"]
    if kind not in ("encoder", "robot"):
        line, col = _locate(text, r"^\s*kind\s*=")
        raise InputError(path, f"unknown model kind {kind!r}; expected \"encoder\" or \"robot\"", line, col)

    effects = []
    tables = doc.get("effect", [])
    if not isinstance(tables, list):
        raise InputError(path, "effects must be [[effect]] tables", *_locate(text, r"^\s*\[?effect"))
    for index, table in enumerate(tables):
        name = table.get("name")
        if not isinstance(name, str):
            line, col = _nth_effect_line(text, index)
            raise InputError(path, "[[effect]] table without name = \"...\"", line, col)
        params = {k: v for k, v in table.items() if k != "name"}
        try:
            effect = REGISTRY.make(kind, name, **params)
        except KeyError:
            line, col = _locate(text, r"^\s*name\s*=\s*[\"']" + re.escape(name) + r"[\"']")
            raise InputError(path, f"unknown {kind} effect {name!r}; known: {', '.join(REGISTRY.names(kind))}",
                             line, col) from None
        problems = effect.check()
        if problems:
            line, col = _locate(text, r"^\s*name\s*=\s*[\"']" + re.escape(name) + r"[\"']")
            raise InputError(path, problems[0], line, col)
        effects.append(effect)
    return Spec(kind, effects, {k: v for k, v in model.items() if k != "kind"}, dict(doc.get("select", {})), path, text)


def _nth_effect_line(text, index):
    hits = [m.start() for m in re.finditer(r"^\s*\[\[effect\]\]", text, flags=re.MULTILINE)]
    if index < len(hits):
        pos = hits[index]
        return text.count("\n", 0, pos) + 1, 1
    return None, None


def load_spec(path) -> Spec:
    return parse_spec(read_text_input(path, "spec file"), str(path))
