"""Rigid frames of a robot campaign: the tracker-to-base transform and the nominal-consistency check.

Pure functions (no files, no printing). Lengths in mm, angles in deg unless a name says
otherwise. A rigid transform is a pair ``(R, t)``, rotation matrix ``R`` (3, 3) and
translation ``t`` (3,) mm, acting on row vectors as ``p' = p @ R.T + t`` (:func:`apply`);
:func:`to_matrix` gives the 4x4 homogeneous matrix of the same transform.

Two uses:

* ``frame = "tracker"`` (contract section 2): the tracker's points are moved into the robot
  base frame by the best rigid fit of the measured points onto the nominal SMR positions
  (:func:`rigid_fit` ``(measured, nominal)``), estimated over the sample poses.
* the nominal-consistency check (:func:`consistency`): after the best rigid fit of the nominal
  positions onto the measured ones, the residual of a real robot is a few mm (its kinematic
  errors, a tool a few cm off); a residual far beyond :data:`MAX_RMS_MM` is bad input, and
  :func:`diagnose` finds the likely cause by refitting under each hypothesis (joint angles in
  radians, positions in metres, a joint's sign flipped, two joints swapped, a wrong tool).

The unit hypotheses (the values in the other joint unit, deg <-> rad, and the other length unit,
mm <-> m: :func:`other_units`, :func:`unit_hypotheses`) and the refit of a hypothesis
(:func:`refit`, its RMS :func:`fit_rms`) are one engine for two callers, each with its own
acceptance rule and message: :func:`diagnose` here, and the unit check of ``jointcal import``
(:func:`pipeline.robot.campaign.importer.check_units`), which names the map's unit line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

# the rigid fit and the rotation angle live with the other frame maths (core/se3); named here too for the
# frame's callers
from ...core.se3 import rigid_fit, rotation_angle_deg  # noqa: F401
from ..arm.kinematics import build_model, placements

# --------------------------------------------------------------------------- thresholds
#: Largest RMS (mm) of the residual after the best rigid fit of the nominal SMR positions onto the
#: measured ones that a real robot's errors produce: about twice the worst real robot and about half
#: the mildest corruption the contract names (docs/speed.md "Measurements behind the code").
MAX_RMS_MM = 10.0
#: Largest error (mm) of one pose after that fit: five times the worst real pose seen; a pose 60 mm off
#: is a wrong measurement or a wrong row, not a robot error.
MAX_POINT_MM = 60.0
#: When at most this fraction of the poses (at least one) are beyond :data:`MAX_POINT_MM` and the
#: rest fit, those poses are named as wrong measurements rather than the whole campaign.
OUTLIER_FRACTION = 0.05
#: With ``frame = "base"`` the fit itself must be near identity: a robot's base error is a few mm and a
#: fraction of a degree, so a translation beyond this (mm) or a rotation beyond :data:`MAX_BASE_ROTATION_DEG`
#: (deg) means the points are in another frame, the tracker's (docs/speed.md "Measurements behind the code").
MAX_BASE_TRANSLATION_MM = 100.0
MAX_BASE_ROTATION_DEG = 3.0
#: A hypothesis explains the data when its refit's RMS is within :data:`MAX_RMS_MM` and at most
#: this fraction of the RMS of the data as given.
EXPLAINS_FRACTION = 0.5


# ------------------------------------------------------------------------ rigid transforms
def apply(R, t, pts):
    """Move points by the rigid transform ``(R, t)``.

    Parameters
    ----------
    R : array_like, shape (3, 3)
    t : array_like, shape (3,), unit of the points
    pts : array_like, shape (n, 3) or (3,)

    Returns
    -------
    ndarray, same shape as ``pts``: ``pts @ R.T + t``.
    """
    pts = np.asarray(pts, float)
    return pts @ np.asarray(R, float).T + np.asarray(t, float)


def invert(R, t):
    """The inverse transform ``(R.T, -R.T t)``."""
    R = np.asarray(R, float)
    return R.T, -R.T @ np.asarray(t, float)


def compose(R1, t1, R2, t2):
    """``(R1, t1) after (R2, t2)``: ``apply(*compose(R1, t1, R2, t2), p) == apply(R1, t1, apply(R2, t2, p))``."""
    R1 = np.asarray(R1, float)
    return R1 @ np.asarray(R2, float), R1 @ np.asarray(t2, float) + np.asarray(t1, float)


def to_matrix(R, t):
    """4x4 homogeneous matrix ``[[R, t], [0, 0, 0, 1]]`` (t in the points' unit, mm here)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, float)
    T[:3, 3] = np.asarray(t, float)
    return T


def from_matrix(T):
    """``(R, t)`` of a 4x4 homogeneous matrix (e.g. the ``tracker_to_base`` metadata)."""
    T = np.asarray(T, float)
    if T.shape != (4, 4):
        raise ValueError(f"expected a 4x4 matrix, got shape {T.shape}")
    return T[:3, :3].copy(), T[:3, 3].copy()


def describe(R, t) -> str:
    """One phrase for a console line: translation (mm) and rotation (deg)."""
    t = np.asarray(t, float)
    return (f"translation [{t[0]:.1f}, {t[1]:.1f}, {t[2]:.1f}] mm (|t| {np.linalg.norm(t):.1f} mm), "
            f"rotation {rotation_angle_deg(R):.2f} deg")


def fit_residuals(src, dst, fit_rows=None):
    """Best rigid fit of ``src`` onto ``dst`` over ``fit_rows`` and every point's residual.

    Returns
    -------
    R, t : the fit (see :func:`rigid_fit`)
    err : ndarray, shape (n,), ``|apply(R, t, src) - dst|`` of every point (unit of the points)
    """
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    rows = slice(None) if fit_rows is None else fit_rows
    R, t = rigid_fit(src[rows], dst[rows])
    return R, t, np.linalg.norm(apply(R, t, src) - dst, axis=1)


def rms(err) -> float:
    err = np.asarray(err, float)
    return float(np.sqrt(np.mean(err ** 2))) if len(err) else 0.0


def fit_rms(src, dst, fit_rows=None, rigid=True) -> float:
    """RMS distance of ``src`` from ``dst`` after the best rigid fit of ``src`` onto ``dst`` (or as they are).

    The one rigid-fit RMS of the nominal-consistency check's hypotheses and of the import's unit
    check: ``rms(fit_residuals(src, dst, fit_rows)[2])``.

    Parameters
    ----------
    src : array_like, shape (n, 3)
        Points to be moved, e.g. nominal SMR positions in the base frame (mm).
    dst : array_like, shape (n, 3)
        Where they should land, same unit, e.g. measured SMR positions (mm).
    fit_rows : array_like of bool, shape (n,), optional
        Pairs the fit is estimated on (default all); the RMS is over every pair.
    rigid : bool
        False: no fit, the RMS of ``src - dst`` as they are (points already in one frame).

    Returns
    -------
    float
        RMS distance, unit of the points (0 for no points).

    Raises
    ------
    ValueError
        From :func:`rigid_fit` (fewer than 3 pairs, non-finite values, collinear points).
    """
    if not rigid:
        return rms(np.linalg.norm(np.asarray(src, float) - np.asarray(dst, float), axis=1))
    return rms(fit_residuals(src, dst, fit_rows)[2])


# ------------------------------------------------------------------------ consistency check
@dataclass
class Consistency:
    """Outcome of :func:`consistency` (lengths mm, angles deg).

    ``ok`` is False when the residual after the best rigid fit is beyond what a robot can do
    (``kind = "residual"``: ``rms_mm > MAX_RMS_MM`` or ``max_mm > MAX_POINT_MM``; ``"outlier"``:
    a few poses beyond :data:`MAX_POINT_MM` while the rest fit) or, with ``frame = "base"``, when
    the fit itself is far from identity (``kind = "frame"``). ``R, t`` is the fit (nominal base
    frame -> measurement frame, on the fit rows; for ``"outlier"`` without the outliers),
    ``err`` every pose's residual (mm), ``worst`` the index of the worst pose. ``cause`` is the
    explanation :func:`diagnose` found (empty when none), ``hypothesis`` its name (``radians``,
    ``metres``, ``sign<j>``, ``swap<j><k>``, ``tool``, ``frame``, ``outlier``), ``file`` the file
    it points at (``poses``, ``tracker`` or ``robot``) and ``column`` the column; ``tool_mm`` the SMR
    (flange frame, mm) that fits when the cause is the tool.
    """

    ok: bool
    rms_mm: float
    max_mm: float
    worst: int
    R: np.ndarray
    t: np.ndarray
    err: np.ndarray
    kind: str = "ok"                 # ok | residual | outlier | frame
    hypothesis: str = ""
    cause: str = ""
    file: str = "tracker"            # poses | tracker | robot
    column: str | None = None
    n_outliers: int = 0
    rest_rms_mm: float = 0.0
    tried: dict = field(default_factory=dict)
    tool_mm: object = None           # hypothesis "tool": the SMR (3,) mm in the flange frame that fits

    @property
    def translation_mm(self) -> float:
        """|t| of the fit, mm."""
        return float(np.linalg.norm(self.t))

    @property
    def rotation_deg(self) -> float:
        """Rotation angle of the fit, deg."""
        return rotation_angle_deg(self.R)

    def tracker_to_base(self):
        """``(R, t)`` moving measured points onto the nominal base frame (inverse of the fit)."""
        return invert(self.R, self.t)


def _fk(model, q_deg):
    """Flange rotations (n, 3, 3) and positions (n, 3) mm in the base frame."""
    Rf, pf = placements(model, np.deg2rad(q_deg), "flange")
    return Rf, pf


def _smr(Rf, pf, tool):
    return pf + Rf @ np.asarray(tool, float)


def _skew(v):
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _exp_so3(w):
    theta = float(np.linalg.norm(w))
    K = _skew(w)
    if theta < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(theta) / theta * K + (1 - np.cos(theta)) / theta ** 2 * K @ K


def fit_tool(Rf, pf, meas, tool0, fit_rows=None, iters=20):
    """Best rigid fit of the nominal positions onto ``meas`` with the tool (SMR) offset free.

    Gauss-Newton on ``meas_i = R (pf_i + Rf_i tool) + t`` (rotation, translation, tool: 9
    unknowns), started from the rigid fit with the nominal tool.

    Parameters
    ----------
    Rf : ndarray, shape (n, 3, 3)
        Flange rotations in the base frame.
    pf : ndarray, shape (n, 3), mm
        Flange positions in the base frame.
    meas : ndarray, shape (n, 3), mm
        Measured SMR positions (any frame).
    tool0 : array_like, shape (3,), mm
        Starting tool offset in the flange frame.
    fit_rows : array_like of bool, shape (n,), optional

    Returns
    -------
    tool : ndarray, shape (3,), mm, in the flange frame
    R, t : the rigid transform base -> measurement frame
    err : ndarray, shape (n,), mm, residual of every pose
    """
    rows = np.arange(len(meas)) if fit_rows is None else np.flatnonzero(np.asarray(fit_rows))
    Rr, pr, mr = Rf[rows], pf[rows], meas[rows]
    tool = np.asarray(tool0, float).copy()
    R, t = rigid_fit(_smr(Rr, pr, tool), mr)
    for _ in range(iters):
        v = _smr(Rr, pr, tool)                                   # (m, 3) base-frame SMR
        res = (v @ R.T + t - mr).reshape(-1)
        J = np.empty((len(rows), 3, 9))
        # d/dw of R exp([w]) v at w = 0 is -R [v]_x
        J[:, :, 0:3] = -np.einsum("ij,njk->nik", R, np.array([_skew(x) for x in v]))
        J[:, :, 3:6] = np.eye(3)
        J[:, :, 6:9] = np.einsum("ij,njk->nik", R, Rr)
        step, *_ = np.linalg.lstsq(J.reshape(-1, 9), -res, rcond=None)
        R = R @ _exp_so3(step[0:3])
        t = t + step[3:6]
        tool = tool + step[6:9]
        if np.linalg.norm(step) < 1e-9 * (1.0 + np.linalg.norm(tool)):
            break
    err = np.linalg.norm(apply(R, t, _smr(Rf, pf, tool)) - meas, axis=1)
    return tool, R, t, err


def _passes(err) -> bool:
    return rms(err) <= MAX_RMS_MM and float(np.max(err)) <= MAX_POINT_MM


def consistency(robot, q_deg, meas_mm, fit_rows=None, frame="base", model=None, explain=True) -> Consistency:
    """Can a real robot with ``robot``'s nominal kinematics have produced these points?

    The nominal SMR positions are rigidly fitted onto the measured points over ``fit_rows``
    and the residual of every pose is judged against :data:`MAX_RMS_MM` and
    :data:`MAX_POINT_MM`; with ``frame = "base"`` the fit must also be near identity
    (:data:`MAX_BASE_TRANSLATION_MM`, :data:`MAX_BASE_ROTATION_DEG`). Cost: one FK pass and a
    rigid fit; when the check fails, :func:`diagnose` adds about 22 FK passes.

    Parameters
    ----------
    robot : pipeline.robot.arm.kinematics.Robot
    q_deg : array_like, shape (n, N), deg
        Joint angles as given in poses.csv (N = the robot's joint count).
    meas_mm : array_like, shape (n, 3), mm
        Measured SMR positions as given in tracker.csv (tracker or base frame).
    fit_rows : array_like of bool, shape (n,), optional
        Poses the rigid fit is estimated on (the sample poses; default all, and all when fewer
        than 3). The residual is judged on every pose.
    frame : {"base", "tracker"}
        The campaign's declared frame: with ``"base"`` a fit far from identity is refused too.
    model : pinocchio.Model, optional
        ``pipeline.robot.arm.kinematics.build_model(robot)`` when already built.
    explain : bool
        Look for the likely cause when the check fails (:func:`diagnose`).

    Returns
    -------
    Consistency

    Raises
    ------
    ValueError
        Fewer than 3 poses, or the fit poses are collinear (see :func:`rigid_fit`).
    """
    q = np.asarray(q_deg, float)
    meas = np.asarray(meas_mm, float)
    n = len(q)
    rows = np.ones(n, bool) if fit_rows is None else np.asarray(fit_rows, bool)
    if rows.sum() < 3:
        rows = np.ones(n, bool)
    model = model or build_model(robot)
    Rf, pf = _fk(model, q)
    nominal = _smr(Rf, pf, robot.tool_xyz_mm)
    R, t, err = fit_residuals(nominal, meas, rows)
    out = Consistency(True, rms(err), float(err.max()), int(np.argmax(err)), R, t, err)
    if _passes(err):
        if frame == "base" and (out.translation_mm > MAX_BASE_TRANSLATION_MM or out.rotation_deg > MAX_BASE_ROTATION_DEG):
            out.ok, out.kind, out.hypothesis = False, "frame", "frame"
            out.cause = ("the points look like they are in the tracker's frame: add frame = \"tracker\" to "
                         f"campaign.toml (the best rigid fit of the points onto the nominal positions is "
                         f"{describe(*invert(R, t))}; a robot's base error is a few mm and a fraction of a degree)")
            out.file, out.column = "tracker", "x_mm"
        return out
    out.ok, out.kind = False, "residual"
    bad = err > MAX_POINT_MM
    keep = ~bad
    if 0 < bad.sum() <= max(1, int(OUTLIER_FRACTION * n)) and (rows & keep).sum() >= 3:
        try:
            R2, t2, err2 = fit_residuals(nominal, meas, rows & keep)
        except ValueError:
            err2 = None
        if err2 is not None and _passes(err2[keep]):
            out.kind, out.hypothesis = "outlier", "outlier"
            out.R, out.t, out.err = R2, t2, err2
            out.worst, out.max_mm = int(np.argmax(err2)), float(err2.max())
            out.n_outliers = int((err2 > MAX_POINT_MM).sum())
            out.rest_rms_mm = rms(err2[keep])
            out.cause = (f"{out.n_outliers} pose(s) beyond {MAX_POINT_MM:g} mm (the worst {out.max_mm:.0f} mm) while "
                         f"the other poses fit within RMS {out.rest_rms_mm:.1f} mm: a wrong measurement, or a "
                         "point_id that belongs to another pose")
            out.file, out.column = "tracker", "x_mm"
            return out
    if explain:
        diagnose(robot, model, q, meas, rows, Rf, pf, out)
    return out


# ------------------------------------------------------------------------ unit hypotheses
#: Factor to degrees of each joint-angle unit, and to mm of each length unit, that a campaign's
#: values may be in (an import map names them; a campaign folder is in deg and mm).
JOINT_UNITS = {"rad": 180.0 / np.pi, "deg": 1.0}
LENGTH_UNITS = {"mm": 1.0, "m": 1000.0}
_OTHER_UNIT = {"rad": "deg", "deg": "rad", "mm": "m", "m": "mm"}


def other_units(units, radians=True) -> list:
    """Every other reading of data read in ``units``, in the order they are tried.

    The same joint unit with the other length unit, then the other joint unit with the given
    length unit and with the other one (both mislabelled).

    Parameters
    ----------
    units : tuple of str
        ``(joint unit, length unit)`` the data were read in: a key of :data:`JOINT_UNITS` and
        one of :data:`LENGTH_UNITS`.
    radians : bool
        Whether angles read in degrees may be radians (the caller's rule, e.g. every value within
        +-2 pi); False leaves out the readings in radians. Degrees are always a reading.

    Returns
    -------
    list of tuple of str
        ``(joint unit, length unit)`` pairs, the given one excluded.
    """
    joint, length = units
    joints = [joint] + ([_OTHER_UNIT[joint]] if _OTHER_UNIT[joint] == "deg" or radians else [])
    return [(j, m) for j in joints for m in (length, _OTHER_UNIT[length]) if (j, m) != (joint, length)]


def unit_hypotheses(q_deg, meas_mm, units=("deg", "mm"), readings=None):
    """The data as they would be had they been read in other units (deg <-> rad, mm <-> m).

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
        Joint angles read in ``units[0]`` and converted to degrees.
    meas_mm : ndarray, shape (n, 3), mm
        Positions read in ``units[1]`` and converted to mm.
    units : tuple of str
        ``(joint unit, length unit)`` they were read in (keys of :data:`JOINT_UNITS`,
        :data:`LENGTH_UNITS`).
    readings : iterable of tuple of str, optional
        ``(joint unit, length unit)`` pairs to try, in order (default :func:`other_units`).

    Yields
    ------
    reading : tuple of str
        The ``(joint unit, length unit)`` of this hypothesis.
    q : ndarray, shape (n, N), deg
        The angles read in it (``q_deg`` itself, the same object, when the joint unit stays,
        so that :func:`refit` reuses its forward kinematics).
    meas : ndarray, shape (n, 3), mm
        The positions read in it (``meas_mm`` itself when the length unit stays).
    """
    joint, length = units
    for j, m in (other_units(units) if readings is None else readings):
        q = q_deg if j == joint else q_deg / JOINT_UNITS[joint] * JOINT_UNITS[j]
        meas = meas_mm if m == length else meas_mm / LENGTH_UNITS[length] * LENGTH_UNITS[m]
        yield (j, m), q, meas


def nominal_smr(robot, model, q_deg):
    """Nominal SMR positions of the joint angles ``q_deg`` (one forward-kinematics pass).

    Parameters
    ----------
    robot : pipeline.robot.arm.kinematics.Robot
    model : pinocchio.Model
        ``build_model(robot)``.
    q_deg : ndarray, shape (n, N), deg

    Returns
    -------
    ndarray, shape (n, 3), mm, in the base frame.
    """
    Rf, pf = _fk(model, q_deg)
    return _smr(Rf, pf, robot.tool_xyz_mm)


def refit(robot, model, q_deg, meas_mm, fit_rows=None, rigid=True, given=None):
    """Refit one hypothesis: the nominal SMR positions of ``q_deg`` and the RMS of ``meas_mm`` about them.

    Parameters
    ----------
    robot : pipeline.robot.arm.kinematics.Robot
    model : pinocchio.Model
        ``build_model(robot)``.
    q_deg : ndarray, shape (n, N), deg
        Joint angles under the hypothesis.
    meas_mm : ndarray, shape (n, 3), mm
        Measured positions under the hypothesis.
    fit_rows : array_like of bool, shape (n,), optional
        Poses the rigid fit is estimated on (default all); see :func:`fit_rms`.
    rigid : bool
        False: the points are compared as they are (base frame), no fit.
    given : tuple, optional
        ``(q, nominal)``: the angles of the data as given, (n, N) deg, and their nominal
        positions, (n, 3) mm; when ``q_deg`` is ``q`` (the hypothesis keeps the angles) those
        positions are used and no forward kinematics run.

    Returns
    -------
    nominal : ndarray, shape (n, 3), mm
    rms : float, mm

    Raises
    ------
    ValueError
        From :func:`rigid_fit`.
    """
    if given is not None and q_deg is given[0]:
        nominal = given[1]
    else:
        nominal = nominal_smr(robot, model, q_deg)
    return nominal, fit_rms(nominal, meas_mm, fit_rows, rigid)


#: the unit hypotheses of the nominal-consistency check, by the reading of a campaign (deg, mm)
#: they stand for: name, file and column it points at, the cause's text
_UNIT_CAUSES = {
    ("rad", "mm"): ("radians", "poses", "q1", ("the joint angles look like radians (q * 180/pi fits the nominal "
                                               "kinematics{fit}); the contract says degrees")),
    ("deg", "m"): ("metres", "tracker", "x_mm", ("x_mm/y_mm/z_mm look like metres (x 1000 fits the nominal "
                                                "kinematics{fit}); the contract says mm")),
}


def _hypotheses(q, meas):
    """(name, file, column, description, q', meas') for every cause :func:`diagnose` tries."""
    for reading, qq, mm in unit_hypotheses(q, meas, ("deg", "mm"), _UNIT_CAUSES):
        yield (*_UNIT_CAUSES[reading], qq, mm)
    for j in range(q.shape[1]):
        qq = q.copy()
        qq[:, j] = -qq[:, j]
        yield (f"sign{j + 1}", "poses", f"q{j + 1}", f"joint {j + 1}'s sign looks flipped (-q{j + 1} fits the nominal "
               "kinematics{fit}): check the joint's direction in the export against robot.toml", qq, meas)
    for j, k in combinations(range(q.shape[1]), 2):
        qq = q.copy()
        qq[:, [j, k]] = qq[:, [k, j]]
        yield (f"swap{j + 1}{k + 1}", "poses", f"q{j + 1}", f"joints {j + 1} and {k + 1} look swapped (q{j + 1} and "
               f"q{k + 1} exchanged fit the nominal kinematics{{fit}}): check the order of the joint columns", qq, meas)
    for j in range(1, q.shape[1]):
        for sign, op in ((1.0, "+"), (-1.0, "-")):
            qq = q.copy()
            qq[:, j] = q[:, j] + sign * q[:, j - 1]
            c = f"q{j + 1} = {{ q{j} = {sign:g}, q{j + 1} = 1 }}"
            yield (f"coupling{j + 1}{op}", "poses", f"q{j + 1}",
                   f"joint {j + 1}'s recorded angle looks coupled to joint {j}'s (q{j + 1} {op} q{j} fits the nominal "
                   f"kinematics{{fit}}), as a FANUC's J3 counts J2 (the J2/J3 interaction): say so with [coupling] "
                   f"{c} in robot.toml, or [joints] coupling = {{ {c} }} in the map", qq, meas)


def diagnose(robot, model, q, meas, rows, Rf, pf, out: Consistency) -> Consistency:
    """Find the likely cause of a failed check; fills ``out.hypothesis/cause/file/column/tried``.

    Each hypothesis of :func:`_hypotheses` (joint angles in radians, positions in metres, each
    joint's sign flipped, each pair of joints swapped, a joint's angle coupled to the one before it,
    + or -) is refitted (:func:`refit`): a rigid fit,
    one FK pass when it changes the angles. The one with the lowest RMS that is within :data:`MAX_RMS_MM`
    and at most :data:`EXPLAINS_FRACTION` of the data's RMS is the likely cause. When none is, a
    wrong tool is tried: a fit with the tool offset free (:func:`fit_tool`). ``out.tried``
    records every hypothesis's RMS (mm).
    """
    best = None
    limit = min(MAX_RMS_MM, EXPLAINS_FRACTION * out.rms_mm)
    given = (q, _smr(Rf, pf, robot.tool_xyz_mm))
    for name, file, column, text, qq, mm in _hypotheses(q, meas):
        try:
            _, r = refit(robot, model, qq, mm, rows, given=given)
        except ValueError:
            continue
        out.tried[name] = r
        if r <= limit and (best is None or r < best[0]):
            best = (r, name, file, column, text.replace("{fit}", f": RMS {r:.1f} mm"))
    if best is None:
        try:
            tool, _, _, err = fit_tool(Rf, pf, meas, robot.tool_xyz_mm, rows)
        except ValueError:
            tool = None
        if tool is not None:
            r = rms(err)
            out.tried["tool"] = r
            if r <= limit:
                off = tool - np.asarray(robot.tool_xyz_mm, float)
                out.tool_mm = tool
                best = (r, "tool", "robot", "xyz_mm",
                        f"a wrong tool: with the SMR at [{tool[0]:.1f}, {tool[1]:.1f}, {tool[2]:.1f}] mm in the "
                        f"flange frame, {np.linalg.norm(off):.0f} mm from [tool] xyz_mm of robot.toml, the points "
                        f"fit the nominal kinematics (RMS {r:.1f} mm)")
    if best is not None:
        _, out.hypothesis, out.file, out.column, out.cause = best
    return out
