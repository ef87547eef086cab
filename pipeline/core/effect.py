"""A model is a list of physical effects: the :class:`Effect` base class and the registry.

Each :class:`Effect` knows

* its **parameters** (what the spec may set, with defaults the data can resolve),
* its **signature**: what it does to the residuals of a model that lacks it, i.e. the
  regressor it adds to the model (``columns`` for the linear encoder model, joint-angle
  offsets / link twists for the robot model),
* its **explanation**: the physical effect in plain words, for reports and diagnosis,
* whether a campaign **can reveal** it at all (one direction only, no timestamps, ...),
* how it **extrapolates** beyond the joint ranges the poses sampled (:attr:`Effect.extrapolates`,
  :attr:`Effect.extrapolation`): a law that *carries* over (geometry, frames, gravity torque through the
  masses, a periodicity over the joint's whole turn) or a curve that is *local* to the sampled ranges;
  :func:`carry_over_line` says it of a model's effects,
* optional hooks with defaults, so that diagnosis, compensation and the command line loop
  over the registry instead of naming effects: :attr:`Effect.acts_on`,
  :attr:`Effect.compensable` / :attr:`Effect.compensation`, :meth:`Effect.candidates`
  (the candidate targets diagnosis tries) and :meth:`Effect.evidence` (what in the
  residuals shows it). A domain may add hooks of its own (the encoder's simulator
  injection: :class:`pipeline.encoder.effects.EncoderEffect`).

The effects of a domain live in its package (:mod:`pipeline.encoder.effects`,
:mod:`pipeline.robot.arm.effects`). Each domain registers its own in one place, its package's
``__init__`` (``REGISTRY.register(*EFFECTS)``), so the spec loader, the models and the
diagnosis see one vocabulary (contract section 3). Nothing here imports a domain.

Effects are constructed from spec parameters only; no work happens in constructors.
"""

from __future__ import annotations

from typing import ClassVar


class Effect:
    """Base class of every physical effect.

    Parameters
    ----------
    **params
        The effect's parameters as written in the spec's ``[[effect]]`` table
        (without ``name``). Stored as given; validated by :meth:`check`.
    """

    name: ClassVar[str] = ""
    domain: ClassVar[str] = ""
    explanation: ClassVar[str] = ""
    signature: ClassVar[str] = ""
    allowed_params: ClassVar[tuple[str, ...]] = ()
    #: what the effect is a function of (e.g. "joint angle", "time within run", "polygon face")
    acts_on: ClassVar[str] = ""
    #: whether a compensation (of the joint, in its controller) can remove it ...
    compensable: ClassVar[bool] = False
    #: ... and how, or why not, in plain words
    compensation: ClassVar[str] = ""
    #: how the effect extends beyond the joint ranges the poses it was fitted on sampled: :data:`CARRIES` (a
    #: physical law of the whole arm, or of the joint's whole turn, that holds there too) or :data:`LOCAL`
    #: (learned over the sampled ranges only: it fades out, or extends a curve no law backs); "" not said
    extrapolates: ClassVar[str] = ""
    #: ... and why, in plain words (one sentence, for the console and reports)
    extrapolation: ClassVar[str] = ""

    def __init__(self, **params):
        self.params = dict(params)

    def __repr__(self):
        inner = ", ".join(f"{k}={v!r}" for k, v in sorted(self.params.items()))
        return f"{type(self).__name__}({inner})"

    def check(self) -> list[str]:
        """Problems with the parameters, as messages (empty when fine)."""
        return [f"effect '{self.name}' has no parameter '{k}' (allowed: {', '.join(self.allowed_params) or 'none'})"
                for k in self.params if k not in self.allowed_params]

    def spec_lines(self) -> str:
        """The ``[[effect]]`` table that adds this effect to a spec."""
        lines = ["[[effect]]", f'name = "{self.name}"']
        for key in sorted(self.params):
            lines.append(f"{key} = {toml_value(self.params[key])}")
        return "\n".join(lines)

    def can_reveal(self, data) -> tuple[bool, str]:
        """Whether ``data`` can show this effect at all, and why not."""
        return True, ""

    def target(self):
        """Contract ``target`` of this effect in a diagnosis (order, joint or None)."""
        return None

    @classmethod
    def candidates(cls, data, present) -> list["Effect"]:
        """The instances of this effect diagnosis should try on ``data`` given the effects
        ``present`` in the model: by default one, with default parameters, unless the model
        already has this effect."""
        return [] if any(e.name == cls.name for e in present) else [cls()]

    def evidence(self, residual, data) -> str:
        """What in the held-out ``residual`` of a model without this effect shows it (one
        sentence for the diagnosis JSON); empty: the domain's adapter says it generically."""
        return ""


#: :attr:`Effect.extrapolates`: the effect's law holds beyond the sampled joint ranges too ...
CARRIES = "carries"
#: ... or it was learned over those ranges only
LOCAL = "local"


def effect_labels(effects) -> list[str]:
    """The names of ``effects``, one per name in the order they first come, each with the joints its instances are
    on when their parameters name them (``joint_map (joints 1 2 5)``)."""
    joints: dict[str, list | None] = {}
    for e in effects:
        js = e.params.get("joints")
        named = isinstance(js, (list, tuple)) and len(js) > 0
        if e.name not in joints:
            joints[e.name] = list(js) if named else None
        elif joints[e.name] is not None and named:
            joints[e.name] += [j for j in js if j not in joints[e.name]]
        else:
            joints[e.name] = None     # one instance on every joint
    return [name if js is None else f"{name} (joint{'s' if len(js) > 1 else ''} {' '.join(map(str, sorted(js)))})"
            for name, js in joints.items()]


def carry_over(effects) -> dict[str, list[Effect]]:
    """A model's ``effects`` by how they extrapolate beyond the sampled joint ranges (:attr:`Effect.extrapolates`):
    ``{"carries": [...], "local": [...], "": [...]}`` (the last: effects that do not say), each in the model's order."""
    out: dict[str, list[Effect]] = {CARRIES: [], LOCAL: [], "": []}
    for e in effects:
        out[e.extrapolates if e.extrapolates in (CARRIES, LOCAL) else ""].append(e)
    return out


def carry_over_line(effects) -> str:
    """In words, which of a model's ``effects`` carry over beyond the joint ranges its poses sampled and which are
    local there (each local one with its reason, :attr:`Effect.extrapolation`); '' for a model without effects."""
    groups = carry_over(effects)
    parts = []
    if groups[CARRIES]:
        parts.append("these of the model's effects carry over: " + ", ".join(effect_labels(groups[CARRIES])))
    if groups[LOCAL]:
        names = list(dict.fromkeys(e.name for e in groups[LOCAL]))
        why = "; ".join(f"{n}: {next(e for e in groups[LOCAL] if e.name == n).extrapolation}" for n in names)
        parts.append(f"these are local: {', '.join(effect_labels(groups[LOCAL]))} ({why})")
    if groups[""]:
        parts.append("these do not say how they extrapolate: " + ", ".join(effect_labels(groups[""])))
    return ("beyond the joint ranges the fit's poses sampled, " + "; ".join(parts)) if parts else ""


def toml_value(value) -> str:
    """A parameter value as TOML (for ``[[effect]]`` lines and specs written back)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):   # an inline table; keys are bare (joint numbers, names)
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    return repr(value)


class Registry:
    """The effects a spec may name, by ``(domain, name)``; filled by each domain's ``register`` call."""

    def __init__(self):
        self._classes: dict[tuple[str, str], type[Effect]] = {}

    def register(self, *classes: type[Effect]) -> None:
        """Make effect classes available to specs under ``(cls.domain, cls.name)``."""
        for cls in classes:
            key = (cls.domain, cls.name)
            if key in self._classes and self._classes[key] is not cls:
                raise ValueError(f"two {cls.domain} effects are named {cls.name!r}")
            self._classes[key] = cls

    def names(self, domain: str) -> list[str]:
        """The registered effect names of a domain, sorted."""
        self._require(domain)
        return sorted(name for dom, name in self._classes if dom == domain)

    def make(self, domain: str, name: str, **params) -> Effect:
        """An effect of ``domain`` by name; KeyError when the domain has none of that name."""
        self._require(domain)
        cls = self._classes.get((domain, name))
        if cls is None:
            raise KeyError(name)
        return cls(**params)

    def _require(self, domain: str) -> None:
        # a programming error, not bad input: the caller never loaded the domain's package
        if not any(dom == domain for dom, _ in self._classes):
            raise LookupError(f"no {domain} effects are registered: import pipeline.{domain} (its __init__ registers them)")


#: the one registry of the package (pipeline.encoder and pipeline.robot register into it)
REGISTRY = Registry()
