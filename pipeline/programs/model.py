"""What the four readers make of a program: its files and its motion targets, in visiting order."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .text import Number, Source

JOINT, CARTESIAN = "joint", "cartesian"
#: how the controller picks the branch of a Cartesian target: the target's own configuration data
#: (``config``), or the branch of the point before, nearest its joints (``previous``)
CONFIG, PREVIOUS = "config", "previous"


@dataclass
class Frame:
    """A tool or base frame as the program resolves it: a 4 x 4 pose (mm) or why it is unknown."""

    pose: np.ndarray | None = None
    why: str = ""
    key: str = ""          # what the program calls it (for --tool / --base: the first unknown one they stand for)
    moving: bool = False   # a frame that moves at run time (a stationary tool, a work object a unit moves): the
                           # targets in it are left as given, never given a --tool / --base


@dataclass
class Target:
    """One motion of a program (a declared target used by several motions appears once per motion).

    Attributes
    ----------
    file, line : str, int
        Where the motion is (the declaration's file and line are in ``decl``).
    name : str
        The target's name (declared) or ``<inline>@line``.
    kind : str
        ``joint`` or ``cartesian``.
    branch : str
        ``config`` (the target's own configuration data) or ``previous`` (a linear move, a UR move, a
        joint move with configuration monitoring off).
    numbers : list of Number
        The target's rewritable numbers (joints: 6 values; Cartesian: the format's pose fields).
    flags : tuple of bool or None
        ``(rear, down, flip)`` the configuration data name (None: not given).
    turn : tuple or None
        The format's turn / quadrant data (KUKA ``T``, ABB ``(cf1, cf4, cf6)``, FANUC ``(t1, t2, t3)``).
    tool, base : Frame
        Cartesian targets: the TCP in the flange frame and the program's base in the robot base frame.
    runtime : str
        Non-empty: computed at run time (left as given), and why.
    decl : tuple
        ``(file index, position)`` of the declaration: the same numbers for every motion using it.
    """

    file: str
    line: int
    name: str
    kind: str
    branch: str = CONFIG
    numbers: list = field(default_factory=list)
    flags: tuple | None = None
    turn: tuple | None = None
    tool: Frame = field(default_factory=Frame)
    base: Frame = field(default_factory=Frame)
    runtime: str = ""
    decl: tuple = ()
    extra: dict = field(default_factory=dict)

    @property
    def values(self) -> np.ndarray:
        return np.array([n.value for n in self.numbers], float)


@dataclass
class Program:
    """A program's files (``sources[0]`` the one given) and its motions in visiting order."""

    format: str                       # "krl", "rapid", "fanuc", "ur"
    sources: list[Source]
    targets: list[Target]
    notes: list[str] = field(default_factory=list)

    def path(self, number: Number) -> str:
        return self.sources[number.file].path
