"""Robot effects (contract section 3, domain ``robot``).

Every robot effect is linear in its parameters through *channels*: coordinates of the
error model of :func:`pipeline.robot.arm.kinematics.build_error_model` -

* ``joints``: joint-angle offsets Delta q (rad), one per joint and pose,
* ``links``: per-link small displacement twist (dx, dy, dz m; ex, ey, ez rad) applied in
  the MDH link frame {i} - the error transfer matrix E_i of the paper's Eq. 8,
* ``base``: 6-dof base frame error, ``tool``: 3-dof SMR offset error.

An effect's :meth:`RobotEffect.basis` returns, for every parameter, the channels it moves
and by how much per unit of the parameter at each pose: a list of ``(coordinate index,
values)`` with values of shape (n,) or a scalar. The predicted SMR position is the forward
kinematics of the error model at ``Q0 + sum_p x_p basis_p`` and its derivative with respect
to ``x_p`` is the frame Jacobian chained with ``basis_p`` - analytic, from pinocchio.
Parameters are carried in *internal units* (mm for lengths, mrad for angles, so that
Jacobian columns are of order 1 mm per unit) and reported in the contract's units
(mm, arcsec).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
import pinocchio as pin

from ...core.effect import CARRIES, LOCAL, REGISTRY, Effect
from ...core.se3 import ARCSEC_PER_MRAD
from ...core.units import REFERENCE_TEMPERATURE_C
from .kinematics import TWIST, ErrorModelIndex, Robot, link_placement

MRAD_ARCSEC = ARCSEC_PER_MRAD  # arcsec per mrad (pipeline.core.se3)
#: Joint numbers of a six-axis robot
#: the joints of the papers' six-joint robots (the default when an effect is not told the robot)
ALL_JOINTS = (1, 2, 3, 4, 5, 6)
#: most joints a robot may have (contract section 2: 4 to 7)
MAX_JOINTS = 7


def joint_count(of=None) -> int:
    """N, the joint count of a Robot (``n_joints``), of RobotData (its q_deg columns), or an int; 6 when None."""
    if of is None:
        return len(ALL_JOINTS)
    if isinstance(of, (int, np.integer)):
        return int(of)
    if hasattr(of, "n_joints"):
        return int(of.n_joints)
    return int(np.shape(of.q_deg)[1])


def all_joints(of=None) -> tuple:
    """1..N of a Robot, RobotData or joint count (see :func:`joint_count`)."""
    return tuple(range(1, joint_count(of) + 1))
#: A compliance is revealable only when the joint's gravity torque varies by at least this much
#: between poses (N m); the UR10's wrist joints carry under 1 N m in any pose.
MIN_TORQUE_SPREAD_NM = 50.0

#: Typical size of a robot error parameter by its reported unit (the yardstick of "nearest the
#: nominal robot", contract section 8: a parameter counts in units of its typical size):
#:
#: * ``arcsec``: 100 arcsec (0.03 deg): joint zero offsets, axis twists and tilts of a machined and
#:   assembled arm are tens to a few hundred arcseconds (the simulated cells draw 20-200; the real
#:   UR10's calibration.conf deltas are of that order); joint maps, harmonics and backlash too.
#: * ``mm``: 0.5 mm: link lengths and offsets of a machined and assembled arm are off by tenths of a
#:   millimetre to a millimetre (the simulated cells draw 0.63 mm).
#: * ``arcsec/kNm``: 50 arcsec per kN m (a joint's compliance; the simulated cells draw 20-60).
#: * ``ppm/K``: 12 ppm/K (the expansion of steel; aluminium 23).
#:
#: The ratio of a length to an angle (0.5 mm / 100 arcsec = 1.03 m) is the lever arm at which a
#: shift and a rotation count alike: a tool-offset error (1 mm typical, :class:`Tool`) seen by an
#: SMR within a few hundred mm of the last joint's axis costs less as a tool offset than as the
#: rotation of the last joint's frame that would move the SMR as much.
TYPICAL_SIZE = {"arcsec": 100.0, "mm": 0.5, "arcsec/kNm": 50.0, "ppm/K": 12.0}
#: Typical size of the tool (SMR) offset error (mm): where an SMR or tool sits on the flange is known
#: from a drawing or a hand measurement of a nest, to about a millimetre (the simulated cells draw
#: 0.3-0.8 mm), less well than the machined links.
TOOL_TYPICAL_MM = 1.0
#: Typical size of the base frame error: the tracker-to-base registration, about a millimetre and
#: 100 arcsec (the simulated cells draw 0.3-0.8 mm and 20-60 arcsec).
BASE_TYPICAL_MM, BASE_TYPICAL_ARCSEC = 1.0, 100.0


@dataclass
class RobotData:
    """Poses of a robot campaign, as arrays with ``n`` rows.

    Attributes
    ----------
    q_deg : ndarray, shape (n, N), deg (N = the robot's joint count, 4 to 7)
        Joint angles the model uses (commanded, or the grating readings of joints 1-3).
    dir : ndarray, shape (n, N), int
        Sign of the last motion of each joint before the pose (+1/-1).
    payload_kg : ndarray, shape (n,), kg
    temperature_c : ndarray, shape (n,), degC
    torque_nm : ndarray, shape (n, N), N m
        Gravity torque of each joint (arm + payload), from pinocchio.
    measured_mm : ndarray, shape (n, 3), mm, or None
        Tracker positions in the robot base frame.
    lower_deg, upper_deg : ndarray, shape (N,), deg
        Joint range of the campaign (robot.toml), used by the Chebyshev variable (Eq. 10).
    point_id : ndarray of str, shape (n,)
    measured_R : ndarray, shape (n, 3, 3), or None
        A 6-DoF probe's measured orientation: the probe frame in the robot base frame (contract
        section 13); None for a campaign of positions only.
    sigma_mm : ndarray, shape (n,), mm, or None
        Stated 1-sigma uncertainty of each position (tracker.csv ``sigma_mm``), None when not stated.
    sigma_arcsec : ndarray, shape (n,), arcsec, or None
        Stated 1-sigma uncertainty of each orientation, per axis (``sigma_arcsec``).
    campaign : ndarray of int, shape (n,), or None
        Which campaign each pose was measured in (1-based, in the order given; contract section 15) when
        several campaigns are fitted together; None for one campaign (every pose the first's).
    mounting_offset : ndarray, shape (n, 6), or None
        Where a pose's campaign states a probe mounting of its own (its robot.toml's ``[tool]``): the error
        model's tool channels (dx, dy, dz in m along the flange axes, then ex, ey, ez in rad about the probe's
        own axes) that put that mounting in place of the model robot's; None: every pose the model robot's.
    """

    q_deg: np.ndarray
    dir: np.ndarray
    payload_kg: np.ndarray
    temperature_c: np.ndarray
    torque_nm: np.ndarray
    lower_deg: np.ndarray
    upper_deg: np.ndarray
    measured_mm: np.ndarray | None = None
    point_id: np.ndarray = field(default_factory=lambda: np.array([], dtype=object))
    measured_R: np.ndarray | None = None
    sigma_mm: np.ndarray | None = None
    sigma_arcsec: np.ndarray | None = None
    campaign: np.ndarray | None = None
    mounting_offset: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.q_deg)

    @property
    def has_orientation(self) -> bool:
        """Whether the poses carry a measured orientation (a 6-DoF probe)."""
        return self.measured_R is not None

    def subset(self, mask) -> "RobotData":
        cut = lambda a: None if a is None else a[mask]  # noqa: E731
        out = RobotData(self.q_deg[mask], self.dir[mask], self.payload_kg[mask], self.temperature_c[mask],
                        self.torque_nm[mask], self.lower_deg, self.upper_deg, cut(self.measured_mm),
                        self.point_id[mask] if len(self.point_id) == self.n else self.point_id,
                        cut(self.measured_R), cut(self.sigma_mm), cut(self.sigma_arcsec), cut(self.campaign),
                        cut(self.mounting_offset))
        if hasattr(self, "grating_joints"):
            out.grating_joints = self.grating_joints
        return out


def _joints(params, default=ALL_JOINTS):
    j = params.get("joints")
    return list(default) if j is None else sorted(int(x) for x in j)


class RobotEffect(Effect):
    """A robot effect: channels of the error model (:meth:`basis`), and everything else about it.

    Hooks beside those of :class:`pipeline.core.effect.Effect`:

    ``diagnosis_order``, ``per_joint``
        where the effect's candidates come in diagnosis's list (results depend on the order),
        and whether it is tried joint by joint (one candidate per joint not yet in the model)
        or once for the whole robot.
    ``on_joint_angle``
        it is an error of a joint's angle: a joint read by a grating hides it.
    ``hidden_syntax``, ``hidden(rng, target, joint)`` (classmethod)
        ``jointcal simulate robot --hidden`` syntax, and a realistic size drawn for it.
    ``inject_truth``, ``inject_joint_error``, ``inject_conditions``, ``inject_measurement``
        (classmethods) how the simulator puts the hidden effect into its virtual cell
        (:mod:`pipeline.robot.cell.simulate`); each does nothing by default.
    """

    domain = "robot"
    allowed_params = ("joints",)
    #: position of the effect's candidates in diagnosis's list (keep: results depend on it)
    diagnosis_order: ClassVar[int] = 100
    #: diagnosis tries it joint by joint (else once for the whole robot)
    per_joint: ClassVar[bool] = True
    #: an error of a joint's angle: a joint read by a grating never shows it
    on_joint_angle: ClassVar[bool] = False
    #: ``jointcal simulate robot --hidden`` syntax (empty: cannot be simulated)
    hidden_syntax: ClassVar[str] = ""
    #: effects whose columns on the same joint overlap this one's (one contains the other's, or both
    #: model the same angle error over the sampled range): a diagnosis round recommends at most one
    #: of such a pair, and never one beside the other already in the model
    overlaps_with: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def candidates(cls, data, present):
        """One candidate per joint the model ``present`` lacks it on (per-joint effects), or one
        for the whole robot unless the model has it."""
        if not cls.per_joint:
            return [] if any(e.name == cls.name for e in present) else [cls()]
        covered = set()
        for e in present:
            if e.name == cls.name:
                joints = e.joints(data) if hasattr(e, "joints") and "joints" in e.allowed_params else None
                covered.update(joints or all_joints(data))
        return [cls(joints=[j]) for j in all_joints(data) if j not in covered]

    # --- the simulator's interface (a hidden effect, ``{"effect": name, ...}``)
    @classmethod
    def hidden(cls, rng, target: str, joint: int) -> dict:
        """A realistic size for ``--hidden NAME[:TARGET]`` drawn from ``rng``; ``joint`` is the
        target joint (drawn when ``target`` is empty)."""
        raise ValueError(f"effect '{cls.name}' cannot be hidden in a simulated campaign")

    @classmethod
    def inject_truth(cls, hidden, true_robot, compliance_deg_per_nm, backlash_deg):
        """The true robot of the cell with the effect (arrays may be changed in place)."""
        return true_robot

    @classmethod
    def inject_joint_error(cls, hidden, q_rad, error_deg) -> None:
        """Add the effect's repeatable joint angle error (deg) at ``q_rad`` (n, N) to ``error_deg``."""

    @classmethod
    def inject_conditions(cls, hidden, payload_kg, temperature_c, t_s, draw):
        """Payload and temperature of the campaign's poses that show the effect; ``draw(k)`` is
        the simulator's generator number ``k`` for conditions."""
        return payload_kg, temperature_c

    @classmethod
    def inject_measurement(cls, hidden, xyz_mm, temperature_c):
        """The tracker positions (n, 3) mm with the effect."""
        return xyz_mm

    def joints(self, robot=None):
        """The effect's joints (1-based): its ``joints``, or every joint of ``robot`` (a Robot,
        RobotData or joint count; the papers' six when None)."""
        return _joints(self.params, all_joints(robot))

    def overlaps(self, other, robot=None) -> list[int]:
        """Joints on which this effect and ``other`` overlap (see :attr:`overlaps_with`); [] for none.
        ``robot`` (a Robot, RobotData or joint count) says what "every joint" is (when None: every joint
        an arm can have, so that an effect on all joints overlaps one on joint 7 too)."""
        if other.name not in self.overlaps_with and self.name not in getattr(other, "overlaps_with", ()):
            return []
        robot = MAX_JOINTS if robot is None else robot
        mine = self.joints(robot) if "joints" in self.allowed_params else []
        theirs = other.joints(robot) if "joints" in getattr(other, "allowed_params", ()) else []
        return sorted(set(mine) & set(theirs))

    def check(self):
        problems = super().check()
        j = self.params.get("joints")
        if j is not None and (not isinstance(j, list) or not all(isinstance(x, int) and not isinstance(x, bool)
                                                               and 1 <= x <= MAX_JOINTS for x in j)):
            problems.append(f"effect '{self.name}': joints must be a list of joint numbers 1..N (N = the robot's "
                            f"joints, at most {MAX_JOINTS})")
        return problems

    def target(self):
        j = self.params.get("joints")
        return int(j[0]) if isinstance(j, list) and len(j) == 1 else None

    # --- the model's interface
    def parameter_names(self, robot: Robot) -> list[str]:
        """Names of the parameters, in the order of :meth:`basis`."""
        raise NotImplementedError

    def units(self, robot: Robot) -> list[tuple[str, float]]:
        """Reported unit of each parameter and the factor internal -> reported."""
        raise NotImplementedError

    def typical_sizes(self, robot: Robot) -> list[float]:
        """Typical size of each parameter on a real robot, in its reported unit (:meth:`units`):
        the yardstick of "nearest the nominal robot" where the measurements cannot tell parameters
        apart (contract section 8; :func:`pipeline.robot.model.identify.physical_subspace`). By default
        from the unit (:data:`TYPICAL_SIZE`); an effect whose parameters are of another size says so."""
        return [TYPICAL_SIZE.get(u, 1.0) for u, _ in self.units(robot)]

    def prepared(self, robot: Robot, data: RobotData) -> "RobotEffect":
        """The effect made ready for a fit on ``data`` (scikit-learn's fit-time state): an effect
        whose parameters depend on the data (a grid over the sampled joint range) returns a copy
        with that state written into its parameters, so that its spec lines reproduce it."""
        return self

    def penalty(self, robot: Robot, n_poses: int):
        """Rows appended to the residuals (mm-equivalent per internal unit of its parameters) that
        keep a many-parameter effect smooth, shape (m, k); None for none."""
        return None

    def checked_values(self, robot: Robot, parameters: list[dict], q_deg) -> list[dict]:
        """What a real robot's error budget applies to, as ``{name, value, unit}``: by default the
        fitted parameters themselves (reported units). An effect whose parameters are not physical
        amounts on their own (polynomial coefficients that may cancel) returns what they produce
        over the sampled joint angles ``q_deg`` (n, N) deg instead."""
        return parameters

    def basis(self, robot: Robot, idx: ErrorModelIndex, data: RobotData) -> list[list[tuple[int, object]]]:
        """Channels of each parameter: list (one per parameter) of ``(coordinate, values)``.

        ``values`` (scalar or shape (n,)) is the channel's change per internal unit of the
        parameter, in SI (rad, m) per (mrad or mm).
        """
        raise NotImplementedError


# ------------------------------------------------------------------------------- effects
class Geometry(RobotEffect):
    name = "geometry"
    diagnosis_order = 0
    per_joint = False
    acts_on = "link frame"
    compensable = True
    compensation = "the calibrated MDH parameters in the controller's kinematic model"
    extrapolates = CARRIES
    extrapolation = ("the link lengths, offsets and axis directions are constants of the arm, the same at "
                     "every joint angle")
    explanation = ("Kinematic (MDH) parameter errors: the real link lengths, offsets and axis directions differ "
                   "from the nominal ones by manufacturing and assembly tolerances (the paper's Eqs. 3-6).")
    signature = ("a smooth position error that follows the arm's geometry: constant joint offsets and link "
                 "length errors; in residuals, a pattern fully explained by the MDH Jacobian")
    PARAMS = ("dtheta", "dd", "da", "dalpha", "dbeta")

    def checked_values(self, robot, parameters, q_deg):
        """None one by one: where the measurements cannot tell them apart, a parameter may carry what
        another would; the fit judges how far the frames move and turn instead
        (:func:`pipeline.robot.model.plausibility.frame_deviations`)."""
        return []

    def parameter_names(self, robot):
        return [f"{p}{i}" for i in self.joints(robot) for p in self.PARAMS]

    def units(self, robot):
        u = {"dtheta": ("arcsec", MRAD_ARCSEC), "dd": ("mm", 1.0), "da": ("mm", 1.0),
             "dalpha": ("arcsec", MRAD_ARCSEC), "dbeta": ("arcsec", MRAD_ARCSEC)}
        return [u[p] for i in self.joints(robot) for p in self.PARAMS]

    def basis(self, robot, idx, data):
        out = []
        for i in self.joints(robot):
            j = robot.joints[i - 1]
            RL = link_placement(j).rotation          # Rx(alpha) Ry(beta)
            Ry = link_placement(type(j)(**{**j.__dict__, "alpha_deg": 0.0})).rotation
            lt, lr = idx.links[i - 1, :3], idx.links[i - 1, 3:]
            out.append([(idx.joints[i - 1], 1e-3)])                                   # dtheta: joint offset
            out.append([(c, 1e-3 * v) for c, v in zip(lt, RL.T @ [0, 0, 1.0])])      # dd along z_{i-1}
            out.append([(c, 1e-3 * v) for c, v in zip(lt, RL.T @ [1.0, 0, 0])])      # da along x
            out.append([(c, 1e-3 * v) for c, v in zip(lr, Ry.T @ [1.0, 0, 0])])      # dalpha about x
            out.append([(lr[1], 1e-3)])                                               # dbeta about y_i
        return out


class Base(RobotEffect):
    name = "base"
    allowed_params = ()
    diagnosis_order = 1
    per_joint = False
    acts_on = "base frame"
    compensable = True
    compensation = "the measured base frame in the controller (a frame registration)"
    extrapolates = CARRIES
    extrapolation = "one rigid frame of the whole robot, the same wherever the arm points"
    hidden_syntax = "base"
    explanation = "The robot base frame measured by the tracker is offset and rotated from where it was set up."
    signature = "a constant offset plus a rotation of all positions about the base origin"

    def parameter_names(self, robot):
        return [f"base_{t}" for t in TWIST]

    def units(self, robot):
        return [("mm", 1.0)] * 3 + [("arcsec", MRAD_ARCSEC)] * 3

    def typical_sizes(self, robot):
        return [BASE_TYPICAL_MM] * 3 + [BASE_TYPICAL_ARCSEC] * 3

    def checked_values(self, robot, parameters, q_deg):
        """Judged as the base frame's shift and turn (:func:`pipeline.robot.model.plausibility.frame_deviations`)."""
        return []

    def basis(self, robot, idx, data):
        return [[(c, 1e-3)] for c in idx.base]

    @classmethod
    def hidden(cls, rng, target, joint):
        """0.3-0.8 mm and 20-60 arcsec."""
        v = rng.normal(size=3)
        return {"effect": "base", "shift_mm": (v / np.linalg.norm(v) * rng.uniform(0.3, 0.8)).tolist(),
                "rot_arcsec": rng.uniform(-60, 60, 3).tolist()}

    @classmethod
    def inject_measurement(cls, hidden, xyz_mm, temperature_c):
        R = pin.rpy.rpyToMatrix(*np.deg2rad(np.asarray(hidden["rot_arcsec"]) / 3600))
        return xyz_mm @ R.T + np.asarray(hidden["shift_mm"])

    @classmethod
    def inject_orientation(cls, hidden, R_meas):
        """A 6-DoF probe's frames (n, 3, 3) in the turned base frame."""
        R = pin.rpy.rpyToMatrix(*np.deg2rad(np.asarray(hidden["rot_arcsec"]) / 3600))
        return np.einsum("ij,njk->nik", R, R_meas)


class _ProbeMounting:
    """What the probe's mounting on the flange is, for ``tool`` and a campaign's own ``campaign_tool``: the
    SMR's (or the probe origin's) offset, mm, and, on a 6-DoF campaign (``orientation = true``), the probe
    frame's turn, arcsec."""

    def oriented(self) -> bool:
        """Whether the probe frame's turn on the flange is a parameter too (a 6-DoF campaign)."""
        return bool(self.params.get("orientation", False))

    def prepared(self, robot, data):
        """On a campaign with orientations the probe frame's turn is fitted too (``orientation = true``)."""
        if getattr(data, "has_orientation", False) and "orientation" not in self.params:
            return type(self)(**{**self.params, "orientation": True})
        return self

    def units(self, robot):
        return [("mm", 1.0)] * 3 + [("arcsec", MRAD_ARCSEC)] * (3 if self.oriented() else 0)

    def typical_sizes(self, robot):
        return [TOOL_TYPICAL_MM] * 3 + [TOOL_TYPICAL_ARCSEC] * (3 if self.oriented() else 0)


class _OneCampaign(RobotEffect):
    """What the effects of one campaign among several share (``campaign_frame``, ``campaign_tool``): the
    campaign they belong to (``campaign = k``, 2, 3, ...: the first campaign has the shared effects), no
    joint of their own, and no place among diagnosis's candidates (the fit adds them when it is given
    several campaigns)."""

    def index(self) -> int:
        """The campaign (1-based) this effect belongs to."""
        return int(self.params.get("campaign", 2))

    def check(self):
        problems = super().check()
        k = self.params.get("campaign", 2)
        if isinstance(k, bool) or not isinstance(k, int) or k < 2:
            problems.append(f"effect '{self.name}': campaign must be the number (2, 3, ...) of a campaign after "
                            "the first")
        return problems

    def target(self):
        return None

    @classmethod
    def candidates(cls, data, present):
        """None: the fit adds the effect when it is given several campaigns, diagnosis never."""
        return []


class CampaignFrame(_OneCampaign):
    """One campaign's own tracker-to-base frame, when several campaigns of one robot are fitted together
    (contract section 15): the 6-dof frame error of the poses of campaign ``campaign`` (1-based, in the order
    the campaigns are given) beside the shared base. The fit adds one for every campaign after the first;
    the first campaign's frame is the model's base frame (``base``). A spec does not name it."""

    name = "campaign_frame"
    allowed_params = ("campaign",)
    diagnosis_order = 1
    per_joint = False
    acts_on = "a campaign's tracker frame"
    compensable = False
    compensation = "none needed on the robot: it is where that campaign's tracker stood, not the robot"
    extrapolates = CARRIES
    extrapolation = "one rigid frame of the campaign's tracker station, the same wherever the arm points"
    explanation = ("Each campaign measures the robot from its own tracker station: its points are in a frame of "
                   "their own, shifted and turned from the first campaign's. The robot is one; each campaign "
                   "after the first keeps its own rigid tracker-to-base frame, fitted with the robot's shared "
                   "parameters.")
    signature = "a constant offset plus a rotation of one campaign's positions, not the other campaigns'"

    def parameter_names(self, robot):
        return [f"campaign{self.index()}_{t}" for t in TWIST]

    def units(self, robot):
        return [("mm", 1.0)] * 3 + [("arcsec", MRAD_ARCSEC)] * 3

    def typical_sizes(self, robot):
        return [BASE_TYPICAL_MM] * 3 + [BASE_TYPICAL_ARCSEC] * 3

    def checked_values(self, robot, parameters, q_deg):
        """Not a robot's error: what is left of one tracker registration (judged by the bounds of its unit)."""
        return parameters

    def basis(self, robot, idx, data):
        own = getattr(data, "campaign", None)
        # a pose of another campaign (or of a data set of one campaign: the first's) is not moved
        mask = 0.0 if own is None else (np.asarray(own) == self.index()).astype(float)
        return [[(c, 1e-3 * mask)] for c in idx.base]


class CampaignTool(_ProbeMounting, _OneCampaign):
    """One campaign's own probe mounting error, when several campaigns of one robot are fitted together and this
    campaign's robot.toml states a probe mounting of its own (contract section 15): the SMR's (or the probe
    origin's) offset error on the flange for the poses of campaign ``campaign`` (and, on a 6-DoF campaign, the
    probe frame's turn), beside the shared ``tool`` of the first campaign's mounting. The fit adds it; its
    nominal mounting is the campaign's robot.toml's (``RobotData.mounting_offset``)."""

    name = "campaign_tool"
    allowed_params = ("campaign", "orientation")
    diagnosis_order = 2
    per_joint = False
    acts_on = "a campaign's probe mounting"
    compensable = True
    compensation = "that campaign's calibrated tool offset in the controller's tool frame"
    extrapolates = CARRIES
    extrapolation = "one rigid mounting on the flange, the same at every pose"
    explanation = ("The probe was mounted otherwise in this campaign (its robot.toml says where): its offset on "
                   "the flange is off by its own error, as the first campaign's is by the shared tool error.")
    signature = "an error that rotates with the flange, on one campaign's poses only"

    def parameter_names(self, robot):
        return [f"campaign{self.index()}_tool_{t}" for t in TWIST[:6 if self.oriented() else 3]]

    def basis(self, robot, idx, data):
        own = getattr(data, "campaign", None)
        mask = 0.0 if own is None else (np.asarray(own) == self.index()).astype(float)
        rot = [[(c, 1e-3 * mask)] for c in idx.tool_rot] if self.oriented() else []
        return [[(c, 1e-3 * mask)] for c in idx.tool] + rot


#: Typical size of the probe frame's turn on the flange (arcsec): a 6-DoF probe's mounting is known from
#: a drawing or the hand-eye measurement to about 0.1 deg (the IPA UR10's T-Mac sits within 0.1 deg of
#: its nominal mounting).
TOOL_TYPICAL_ARCSEC = 360.0


class Tool(_ProbeMounting, RobotEffect):
    """The SMR (or the probe's origin) offset on the flange; with ``orientation = true`` (set by the
    fit when the campaign has a 6-DoF probe's orientations) also the probe frame's turn on the flange."""

    name = "tool"
    allowed_params = ("orientation",)
    diagnosis_order = 2
    per_joint = False
    acts_on = "tool"
    compensable = True
    compensation = "the calibrated tool (SMR) offset in the controller's tool frame"
    extrapolates = CARRIES
    extrapolation = "one rigid mounting on the flange, the same at every pose"
    hidden_syntax = "tool"
    explanation = "The SMR sits elsewhere on the end effector than robot.toml says (tool offset error)."
    signature = "an error that rotates with the flange: depends on the wrist orientation, not on position"

    def check(self):
        problems = super().check()
        if not isinstance(self.params.get("orientation", False), bool):
            problems.append("effect 'tool': orientation must be true or false")
        return problems

    def parameter_names(self, robot):
        return [f"tool_{t}" for t in TWIST[:6 if self.oriented() else 3]]

    def checked_values(self, robot, parameters, q_deg):
        """Judged as the SMR's shift on the flange (:func:`pipeline.robot.model.plausibility.frame_deviations`)."""
        return []

    def basis(self, robot, idx, data):
        rot = [[(c, 1e-3)] for c in idx.tool_rot] if self.oriented() else []
        return [[(c, 1e-3)] for c in idx.tool] + rot

    @classmethod
    def hidden(cls, rng, target, joint):
        """0.3-0.8 mm SMR offset."""
        v = rng.normal(size=3)
        return {"effect": "tool", "shift_mm": (v / np.linalg.norm(v) * rng.uniform(0.3, 0.8)).tolist()}

    @classmethod
    def inject_truth(cls, hidden, true_robot, compliance_deg_per_nm, backlash_deg):
        return replace(true_robot, tool_xyz_mm=tuple(np.add(true_robot.tool_xyz_mm, hidden["shift_mm"])))


def chebyshev_variable(q_deg, lower_deg, upper_deg):
    """Eq. 10: joint angle mapped to [-1, 1] over the joint range."""
    return 2.0 * (np.asarray(q_deg, float) - lower_deg) / (upper_deg - lower_deg) - 1.0


def chebyshev_polys(x, order):
    """c_0..c_m of Eq. 9 at x; shape (..., m + 1)."""
    x = np.asarray(x, float)
    c = [np.ones_like(x), x]
    for _ in range(2, order + 1):
        c.append(2 * x * c[-1] - c[-2])
    return np.stack(c[: order + 1], axis=-1)


class Chebyshev(RobotEffect):
    name = "chebyshev"
    allowed_params = ("order", "joints")
    diagnosis_order = 7
    #: the error transfer matrix of link j holds joint j's angle error against its own angle
    overlaps_with = ("joint_map", "joint_harmonic")
    acts_on = "link frame"
    compensable = True
    compensation = ("the error transfer matrices in the controller's model (a joint-angle dependent "
                    "correction of every link frame)")
    extrapolates = LOCAL
    extrapolation = ("a polynomial in each joint's angle fitted over the angles the poses sampled; beyond them "
                     "it extends the polynomial, not a physical law, and no measurement holds it there")
    explanation = ("Error transfer matrices (the second paper's Eqs. 7-13): every link frame carries a small "
                   "translation and rotation that varies smoothly with its joint angle, written as Chebyshev "
                   "polynomials; order 0 is geometry, higher orders are friction, transmission error and "
                   "flexibility.")
    signature = "smooth position error that varies with single joint angles, beyond the MDH geometry"

    def order(self):
        return int(self.params.get("order", 3))

    def check(self):
        problems = super().check()
        o = self.params.get("order", 3)
        if not isinstance(o, int) or isinstance(o, bool) or not 0 <= o <= 8:
            problems.append("effect 'chebyshev': order must be an integer 0..8")
        return problems

    def parameter_names(self, robot):
        # lambda for rotations (e*), gamma for translations (d*), Eq. 10
        return [f"{'gamma' if t[0] == 'd' else 'lambda'}_{j}_{t}_{i}"
                for i in self.joints(robot) for t in TWIST for j in range(self.order() + 1)]

    def units(self, robot):
        return [("mm", 1.0) if t[0] == "d" else ("arcsec", MRAD_ARCSEC)
                for i in self.joints(robot) for t in TWIST for j in range(self.order() + 1)]

    def checked_values(self, robot, parameters, q_deg):
        """The largest translation (mm) and rotation (arcsec) of each error transfer matrix over the
        sampled range of its joint: the coefficients of a high order may be large and cancel."""
        value = {p["name"]: p["value"] for p in parameters}
        out = []
        q = np.asarray(q_deg, float)
        for i in self.joints(robot):
            grid = np.linspace(q[:, i - 1].min(), q[:, i - 1].max(), 61)
            C = chebyshev_polys(chebyshev_variable(grid, robot.lower_deg[i - 1], robot.upper_deg[i - 1]), self.order())
            for t in TWIST:
                kind = "gamma" if t[0] == "d" else "lambda"
                coef = np.array([value[f"{kind}_{j}_{t}_{i}"] for j in range(self.order() + 1)])
                out.append({"name": f"{'delta' if t[0] == 'd' else 'epsilon'}_{t}_{i} over the sampled range",
                            "value": float(np.max(np.abs(C @ coef))), "unit": "mm" if t[0] == "d" else "arcsec"})
        return out

    def basis(self, robot, idx, data):
        out = []
        for i in self.joints(robot):
            x = chebyshev_variable(data.q_deg[:, i - 1], data.lower_deg[i - 1], data.upper_deg[i - 1])
            C = chebyshev_polys(x, self.order())
            for k in range(6):
                for j in range(self.order() + 1):
                    out.append([(idx.links[i - 1, k], 1e-3 * C[:, j])])
        return out


class Compliance(RobotEffect):
    name = "compliance"
    diagnosis_order = 5
    on_joint_angle = True
    acts_on = "joint angle"
    compensable = True
    compensation = "the controller adds compliance times the gravity torque of the pose and payload to the joint command"
    extrapolates = CARRIES
    extrapolation = ("the gravity torque at any pose follows from the arm's real masses and the payload, and "
                     "the joint gives way by its compliance times that torque there too")
    hidden_syntax = "compliance:J"
    explanation = ("The joints give way under load: each joint deflects by its compliance times the gravity "
                   "torque it carries (arm weight and payload), so the arm sags more when stretched out or loaded.")
    signature = "error that grows with the gravity torque of a joint (pose- and payload-dependent droop)"

    def parameter_names(self, robot):
        return [f"compliance{i}" for i in self.joints(robot)]

    def units(self, robot):
        # internal: mrad per kN m; reported arcsec per kN m
        return [("arcsec/kNm", MRAD_ARCSEC)] * len(self.joints(robot))

    def basis(self, robot, idx, data):
        return [[(idx.joints[i - 1], 1e-3 * data.torque_nm[:, i - 1] / 1000.0)] for i in self.joints(robot)]

    def poses_can_help(self, data) -> bool:
        """Whether other poses could reveal it: not when no joint carries any gravity torque (a robot
        without masses, no payload)."""
        return bool(np.any(np.asarray(data.torque_nm) != 0.0))

    def can_reveal(self, data):
        cols = [i - 1 for i in self.joints(data)]
        if not self.poses_can_help(data):
            return False, ("every gravity torque is 0: the robot has no masses (mass_kg = 0 on every link of "
                           "robot.toml; a URDF without <inertial> gives none) and the poses no payload; no choice of "
                           "poses can reveal it: give the links' mass_kg and com_mm (or the URDF's <inertial>)")
        spread = np.ptp(data.torque_nm[:, cols], axis=0)
        if np.all(spread < MIN_TORQUE_SPREAD_NM):
            tau = np.abs(data.torque_nm[:, cols]).max()
            if tau < MIN_TORQUE_SPREAD_NM:
                return False, (f"the gravity torque of joint {', '.join(map(str, self.joints(data)))} stays below "
                               f"{tau:.2g} N m on every pose (little weight beyond it): too small to bend it measurably")
            return False, (f"the gravity torque of joint {', '.join(map(str, self.joints(data)))} changes by only "
                           f"{spread.max():.2g} N m between these poses (same posture and payload)")
        return True, ""

    @classmethod
    def hidden(cls, rng, target, joint):
        """+20-60 arcsec/kNm on joint J (joint 2 when none is named), with a payload that varies 0-150 kg."""
        return {"effect": "compliance", "joint": joint if target else 2, "arcsec_per_knm": float(rng.uniform(20, 60))}

    @classmethod
    def inject_truth(cls, hidden, true_robot, compliance_deg_per_nm, backlash_deg):
        compliance_deg_per_nm[hidden["joint"] - 1] += hidden["arcsec_per_knm"] / 3600 / 1000
        return true_robot

    @classmethod
    def inject_conditions(cls, hidden, payload_kg, temperature_c, t_s, draw):
        return np.round(draw(7).uniform(0.0, 150.0, len(payload_kg)), 1), temperature_c


class Backlash(RobotEffect):
    name = "backlash"
    diagnosis_order = 4
    on_joint_angle = True
    acts_on = "joint angle"
    compensable = True
    compensation = "the controller adds half the play to the command, by the direction the joint last moved"
    extrapolates = CARRIES
    extrapolation = "one play per joint, the same at every angle, taken up by the direction the joint last moved"
    hidden_syntax = "backlash:J"
    explanation = ("Play in the gears: a joint stops short by half its backlash on one side or the other, "
                   "depending on the direction it last moved.")
    signature = "residuals of poses reached with a joint turning forwards and backwards differ by a constant"

    def parameter_names(self, robot):
        return [f"half_backlash{i}" for i in self.joints(robot)]

    def units(self, robot):
        return [("arcsec", MRAD_ARCSEC)] * len(self.joints(robot))

    def basis(self, robot, idx, data):
        return [[(idx.joints[i - 1], 1e-3 * data.dir[:, i - 1].astype(float))] for i in self.joints(robot)]

    def can_reveal(self, data):
        both = [np.unique(data.dir[:, i - 1]).size > 1 for i in self.joints(data)]
        if not any(both):
            return False, "every joint reached its poses turning one way only; both directions are needed"
        return True, ""

    @classmethod
    def hidden(cls, rng, target, joint):
        """40-120 arcsec more play on joint J."""
        return {"effect": "backlash", "joint": joint, "arcsec": float(rng.uniform(40, 120))}

    @classmethod
    def inject_truth(cls, hidden, true_robot, compliance_deg_per_nm, backlash_deg):
        backlash_deg[hidden["joint"] - 1] += hidden["arcsec"] / 3600
        return true_robot


class Thermal(RobotEffect):
    name = "thermal"
    allowed_params = ()
    diagnosis_order = 3
    per_joint = False
    acts_on = "link lengths (temperature)"
    compensable = True
    compensation = "the controller scales the link lengths by the expansion at the measured temperature"
    extrapolates = CARRIES
    extrapolation = "one expansion of every link with temperature, the same at every joint angle"
    hidden_syntax = "thermal"
    explanation = "The links grow with temperature (steel/aluminium expansion): all lengths scale by alpha * (T - 20 degC)."
    signature = "error proportional to the distance from the base, growing with temperature"

    def parameter_names(self, robot):
        return ["expansion_ppm_per_K"]

    def units(self, robot):
        return [("ppm/K", 1.0)]

    def basis(self, robot, idx, data):
        dT = data.temperature_c - REFERENCE_TEMPERATURE_C
        ch = []
        for i, j in enumerate(robot.joints):
            RL = link_placement(j).rotation
            v = RL.T @ np.array([j.a_mm, 0.0, j.d_mm]) * 1e-3  # m
            for k in range(3):
                if v[k] != 0.0:
                    ch.append((idx.links[i, k], 1e-6 * v[k] * dT))
        for k in range(3):
            if robot.tool_xyz_mm[k] != 0.0:
                ch.append((idx.tool[k], 1e-9 * robot.tool_xyz_mm[k] * dT))
        return [ch]

    def can_reveal(self, data):
        if np.ptp(data.temperature_c) < 1.0:
            return False, "the temperature hardly changes between poses (less than 1 K)"
        return True, ""

    @classmethod
    def hidden(cls, rng, target, joint):
        """8-14 ppm/K, with an 8 K temperature rise over the campaign."""
        return {"effect": "thermal", "ppm_per_K": float(rng.uniform(8, 14))}

    @classmethod
    def inject_conditions(cls, hidden, payload_kg, temperature_c, t_s, draw):
        return payload_kg, 18.0 + 8.0 * t_s / t_s[-1] + draw(8).normal(0, 0.2, len(t_s))

    @classmethod
    def inject_measurement(cls, hidden, xyz_mm, temperature_c):
        if temperature_c is None:
            return xyz_mm
        return xyz_mm * (1.0 + hidden["ppm_per_K"] * 1e-6 * (np.asarray(temperature_c)[:, None] - REFERENCE_TEMPERATURE_C))


#: the highest order of a periodic joint error diagnosis tries (cycles per joint turn, as the
#: first paper's joint modules)
JH_MAX_ORDER = 16


def jh_orders(q_deg, top=JH_MAX_ORDER):
    """Orders of a periodic joint error worth a candidate on these poses.

    Over a joint range of R degrees, order k completes k R / 360 cycles. Below half a cycle
    every order looks alike (an offset, a slope and a gentle curve, mostly taken up by the
    joint's MDH offset), so order 1 stands for all of them; every order that completes half a
    cycle or more, up to ``top``, is a candidate of its own.
    """
    R = float(np.ptp(q_deg))
    if R <= 0:
        return []
    first = max(1, int(np.ceil(180.0 / R)))
    return sorted({1} | set(range(min(first, top + 1), top + 1)))


class JointHarmonic(RobotEffect):
    name = "joint_harmonic"
    allowed_params = ("joints", "orders")
    diagnosis_order = 8
    #: over the sampled range a periodic error of joint j is one of joint j's angle-error curves
    overlaps_with = ("joint_map", "chebyshev")
    on_joint_angle = True
    acts_on = "joint angle"
    compensable = True
    compensation = "a table of the joint's angle error over its angle, subtracted from the command"
    extrapolates = CARRIES
    extrapolation = ("sinusoids over the joint's whole turn, as an encoder's or a transmission's periodic error "
                     "is: the same law at angles the poses did not reach")
    hidden_syntax = "joint_harmonic:J"
    explanation = ("Periodic joint angle error of encoder and reducer (the first paper): each joint's angle is "
                   "off by a sum of sinusoids in the joint angle.")
    signature = "residual that oscillates with one joint's angle"

    def orders(self):
        return sorted(int(o) for o in self.params.get("orders", [1, 2]))

    def parameter_names(self, robot):
        return [f"{ab}{k}_joint{i}" for i in self.joints(robot) for k in self.orders() for ab in "AB"]

    def units(self, robot):
        return [("arcsec", MRAD_ARCSEC)] * (2 * len(self.joints(robot)) * len(self.orders()))

    def basis(self, robot, idx, data):
        out = []
        for i in self.joints(robot):
            th = np.deg2rad(data.q_deg[:, i - 1])
            for k in self.orders():
                out.append([(idx.joints[i - 1], 1e-3 * np.cos(k * th))])
                out.append([(idx.joints[i - 1], 1e-3 * np.sin(k * th))])
        return out

    def target(self):
        j = self.params.get("joints")
        return int(j[0]) if isinstance(j, list) and len(j) == 1 else None

    @classmethod
    def candidates(cls, data, present):
        """One candidate per joint and order (:func:`jh_orders` of the joint's sampled range), as for
        an encoder, unless the model has that joint and order."""
        have = {(j, k) for e in present if e.name == cls.name for j in e.joints(data) for k in e.orders()}
        return [cls(joints=[j], orders=[k]) for j in all_joints(data) for k in jh_orders(data.q_deg[:, j - 1])
                if (j, k) not in have]

    @classmethod
    def hidden(cls, rng, target, joint):
        """Order 4-8 per turn, 15-40 arcsec on joint J."""
        return {"effect": "joint_harmonic", "joint": joint, "order": int(rng.integers(4, 9)),
                "arcsec": float(rng.uniform(15, 40)), "phase_deg": float(rng.uniform(0, 360))}

    @classmethod
    def inject_joint_error(cls, hidden, q_rad, error_deg):
        j = hidden["joint"] - 1
        error_deg[:, j] += hidden["arcsec"] / 3600 * np.sin(hidden["order"] * q_rad[:, j] + np.deg2rad(hidden["phase_deg"]))


#: Beyond its joint's sampled range a joint map fades to zero over this many degrees, back to geometry
#: where it has seen nothing (the real UR10's other series, docs/speed.md "Measurements behind the code").
JOINT_MAP_FADE_DEG = 5.0
#: Default grid step (deg) and curvature penalty (relative to the number of poses) of a joint map: the
#: coarsest step as good held out as a finer one on the real UR10 (docs/speed.md "Measurements behind the code").
JOINT_MAP_STEP_DEG = 2.0
JOINT_MAP_SMOOTHING = 1e-4
#: A pull of every grid value towards zero (relative to the number of poses): a stretch no pose covers
#: decays to zero within a few knots instead of continuing its neighbours' slope.
JOINT_MAP_RIDGE = 1e-4
#: Inside its sampled range a joint map bridges a stretch without sample poses up to this wide by
#: interpolating between the measured knots on either side; across a wider stretch it fades to zero from
#: either side over :data:`JOINT_MAP_FADE_DEG`, as beyond the range's ends (two fades: they meet in the middle).
#: A grid campaign leaves such stretches (a joint held on a lattice of angles, a joint range sampled in lobes):
#: a knot no pose reaches was a free value the fit left at 0, a comb of spikes and zeros between the lattice.
JOINT_MAP_GAP_DEG = 2 * JOINT_MAP_FADE_DEG


def sampled_gaps(q_deg, step_deg) -> list:
    """Stretches between consecutive sampled angles of one joint in which a map knot would have no pose within
    a grid step of it (wider than two steps).

    Parameters
    ----------
    q_deg : ndarray, shape (n,), deg
        The joint's sampled angles.
    step_deg : float, deg
        The map's grid step.

    Returns
    -------
    list of [low, high] (deg, rounded to 1e-6 deg as the map's range): the sampled angles on either side.
    """
    s = np.unique(np.round(np.asarray(q_deg, float), 6))
    wide = np.flatnonzero(np.diff(s) > 2.0 * step_deg)
    return [[float(s[i]), float(s[i + 1])] for i in wide]


def joint_map_basis(q_deg, knots, fade_deg=JOINT_MAP_FADE_DEG):
    """Piecewise-linear "hat" functions on ``knots``, fading to 0 beyond the first and last knot.

    Parameters
    ----------
    q_deg : ndarray, shape (n,), deg
    knots : ndarray, shape (K,), deg, increasing

    Returns
    -------
    ndarray, shape (n, K): weight of each knot's value at each angle (rows sum to 1 inside).
    """
    q = np.asarray(q_deg, float)
    qc = np.clip(q, knots[0], knots[-1])
    K = len(knots)
    B = np.zeros((len(q), K))
    if K == 1:
        B[:, 0] = 1.0
    else:
        i = np.clip(np.searchsorted(knots, qc) - 1, 0, K - 2)
        w = (qc - knots[i]) / (knots[i + 1] - knots[i])
        B[np.arange(len(q)), i] = 1.0 - w
        B[np.arange(len(q)), i + 1] = w
    beyond = np.maximum(knots[0] - q, q - knots[-1])
    return B * np.clip(1.0 - np.maximum(beyond, 0.0) / fade_deg, 0.0, 1.0)[:, None]


def curvature_rows(knots, segments, step_deg) -> np.ndarray:
    """Second divided differences of a map's values on uneven ``knots`` (K,) deg, within each segment (index
    arrays), scaled to a grid of ``step_deg``: the rows [1, -2, 1] on even knots. Shape (m, K)."""
    rows = []
    for seg in segments:
        for a, b, c in zip(seg[:-2], seg[1:-1], seg[2:]):
            h1, h2 = knots[b] - knots[a], knots[c] - knots[b]
            r = np.zeros(len(knots))
            scale = step_deg ** 2 * 2.0 / (h1 + h2)
            r[a], r[b], r[c] = scale / h1, -scale * (1.0 / h1 + 1.0 / h2), scale / h2
            rows.append(r)
    return np.array(rows) if rows else np.zeros((0, len(knots)))


class JointMap(RobotEffect):
    name = "joint_map"
    allowed_params = ("joints", "step_deg", "smoothing", "range_deg", "gaps_deg")
    diagnosis_order = 6
    overlaps_with = ("chebyshev", "joint_harmonic")
    on_joint_angle = True
    acts_on = "joint angle"
    compensable = True
    compensation = "a table of the joint's angle error over its angle, subtracted from the command"
    extrapolates = LOCAL
    extrapolation = ("an interpolation table over the joint range the poses sampled, which fades to zero beyond "
                     "it: what the joint does there was not measured")
    explanation = ("Angle-dependent joint error: each joint's angle is off by an amount that varies with its own "
                   "angle - the transmission and encoder errors of the first paper, of every order, joint by joint. "
                   "Learned as a smooth curve on a grid over the joint range the poses sampled; it fades to zero "
                   "beyond that range, where the model falls back to its geometry.")
    signature = "residual that follows one joint's own angle in fine detail, repeatably from pose to pose"

    def step(self) -> float:
        return float(self.params.get("step_deg", JOINT_MAP_STEP_DEG))

    def smoothing(self) -> float:
        return float(self.params.get("smoothing", JOINT_MAP_SMOOTHING))

    def check(self):
        problems = super().check()
        st = self.params.get("step_deg", JOINT_MAP_STEP_DEG)
        if isinstance(st, bool) or not isinstance(st, (int, float)) or not 0.1 <= st <= 90:
            problems.append("effect 'joint_map': step_deg must be a number of degrees in 0.1..90")
        sm = self.params.get("smoothing", JOINT_MAP_SMOOTHING)
        if isinstance(sm, bool) or not isinstance(sm, (int, float)) or not sm >= 0:
            problems.append("effect 'joint_map': smoothing must be a number >= 0")
        rng = self.params.get("range_deg")
        if rng is not None and (not isinstance(rng, dict) or not all(
                isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v) and v[0] <= v[1]
                for v in rng.values())):
            problems.append("effect 'joint_map': range_deg must map joint numbers to [low, high] in deg")
        gaps = self.params.get("gaps_deg")
        if gaps is not None and (not isinstance(gaps, dict) or not all(
                isinstance(g, list) and all(isinstance(v, list) and len(v) == 2 and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) for x in v) and v[0] <= v[1] for v in g)
                for g in gaps.values())):
            problems.append("effect 'joint_map': gaps_deg must map joint numbers to lists of [low, high] in deg")
        return problems

    def prepared(self, robot, data):
        if self.params.get("range_deg") is not None:
            return self
        q = np.asarray(data.q_deg, float)
        rng = {str(j): [float(np.round(q[:, j - 1].min(), 6)), float(np.round(q[:, j - 1].max(), 6))]
               for j in self.joints(robot)}
        gaps = {str(j): g for j in self.joints(robot) if (g := sampled_gaps(q[:, j - 1], self.step()))}
        params = {k: v for k, v in self.params.items() if k != "gaps_deg"}
        return type(self)(**{**params, "range_deg": rng, **({"gaps_deg": gaps} if gaps else {})})

    def gaps(self, j: int) -> list:
        """The stretches [low, high] (deg) of joint ``j``'s sampled range without sample poses (``gaps_deg``)."""
        return [list(map(float, g)) for g in (self.params.get("gaps_deg") or {}).get(str(j), [])]

    def knots(self, j: int) -> np.ndarray:
        """Joint ``j``'s knots (deg, increasing): the grid over its sampled range, without the knots that lie in a
        gap (:meth:`gaps`) with no sample pose within a grid step of them."""
        rng = self.params.get("range_deg")
        if rng is None or str(j) not in rng:
            raise ValueError("joint_map: the joint range is set when the model is fitted (prepared)")
        lo, hi = rng[str(j)]
        k = max(2, int(np.ceil((hi - lo) / self.step() - 1e-9)) + 1)
        grid = np.linspace(lo, hi if hi > lo else lo + 1e-6, k)
        keep = np.ones(grid.size, bool)
        for a, b in self.gaps(j):
            keep &= ~((grid - self.step() >= a - 1e-9) & (grid + self.step() <= b + 1e-9))
        return grid[keep]

    def segments(self, j: int) -> list:
        """Joint ``j``'s knots (:meth:`knots`) split at every gap wider than :data:`JOINT_MAP_GAP_DEG`: index
        arrays into the knots; the map interpolates within a segment and fades to zero beyond its ends."""
        kn = self.knots(j)
        cuts = sorted(0.5 * (a + b) for a, b in self.gaps(j) if b - a > JOINT_MAP_GAP_DEG)
        side = np.searchsorted(np.asarray(cuts, float), kn)
        return [np.flatnonzero(side == s) for s in range(len(cuts) + 1) if np.any(side == s)]

    def map_basis(self, j: int, q_deg) -> np.ndarray:
        """Weight of each of joint ``j``'s knots at the angles ``q_deg`` (n,) deg: shape (n, K); hat functions
        within each segment (:meth:`segments`), fading to zero beyond a segment's ends."""
        kn = self.knots(j)
        B = np.zeros((len(np.asarray(q_deg)), kn.size))
        for seg in self.segments(j):
            B[:, seg] = joint_map_basis(q_deg, kn[seg])
        return B

    def parameter_names(self, robot):
        return [f"map{j}_{k:03d}" for j in self.joints(robot) for k in range(len(self.knots(j)))]

    def units(self, robot):
        return [("arcsec", MRAD_ARCSEC)] * sum(len(self.knots(j)) for j in self.joints(robot))

    def basis(self, robot, idx, data):
        out = []
        for j in self.joints(robot):
            # each knot's values contiguous (a column of the (n, K) basis is strided)
            BT = 1e-3 * np.ascontiguousarray(self.map_basis(j, data.q_deg[:, j - 1]).T)
            out += [[(idx.joints[j - 1], BT[k])] for k in range(BT.shape[0])]
        return out

    def penalty(self, robot, n_poses):
        import scipy.linalg

        blocks = []
        for j in self.joints(robot):
            kn = self.knots(j)
            K = len(kn)
            if not self.gaps(j):
                D2 = np.diff(np.eye(K), 2, axis=0) if K > 2 else np.zeros((0, K))
            else:
                D2 = curvature_rows(kn, self.segments(j), self.step())
            # curvature (smooth curve) and the mean level (an offset is geometry's dtheta)
            blocks.append(np.vstack([np.sqrt(self.smoothing() * n_poses) * D2, np.sqrt(n_poses) * np.ones((1, K)) / K,
                                     np.sqrt(JOINT_MAP_RIDGE * n_poses) * np.eye(K)]))
        return scipy.linalg.block_diag(*blocks)

    def checked_values(self, robot, parameters, q_deg):
        out, k = [], 0
        for j in self.joints(robot):
            K = len(self.knots(j))
            v = np.array([p["value"] for p in parameters[k:k + K]])
            out.append({"name": f"joint {j}'s angle error map (largest)", "value": float(np.max(np.abs(v))),
                        "unit": "arcsec"})
            k += K
        return out

    def amplitudes_arcsec(self, parameters) -> dict:
        """Half the peak-to-peak of each joint's map (arcsec)."""
        out, k = {}, 0
        joints = self.params.get("joints") or sorted(int(x) for x in self.params.get("range_deg", {}))
        for j in sorted(int(x) for x in joints):
            K = len(self.knots(j))
            v = np.array([p["value"] for p in parameters[k:k + K]])
            out[j] = float(np.ptp(v) / 2)
            k += K
        return out


#: the robot vocabulary, registered by pipeline.robot
EFFECTS = (Geometry, Base, Tool, Chebyshev, Compliance, Backlash, Thermal, JointHarmonic, JointMap, CampaignFrame,
           CampaignTool)


def effect_classes(registry=REGISTRY) -> list[type[RobotEffect]]:
    """The robot effect classes of ``registry``, in diagnosis order (its candidates come in this order)."""
    classes = [type(registry.make("robot", name)) for name in registry.names("robot")]
    return sorted(classes, key=lambda cls: (cls.diagnosis_order, cls.name))


def effect_class(name: str, registry=REGISTRY) -> type[RobotEffect]:
    """The robot effect class of ``name`` (KeyError when there is none)."""
    return type(registry.make("robot", name))
