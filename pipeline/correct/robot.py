"""Corrected commands from a fitted robot model (contract section 8, ``jointcal correct``).

A program gives, per point, the nominal joint values ``q`` (a taught or offline-programmed pose) and
optionally the point the SMR / tool must reach (default: where the nominal kinematics put ``q``).
The robot, commanded ``q``, lands where the fitted model predicts - with every effect of the model:
geometry, base, tool, joint maps and harmonics, compliance under the row's payload, backlash with
the row's approach direction, thermal expansion at the row's temperature. :func:`correct_commands`
finds the commands ``q + dq`` at which the model's prediction is the point to reach:

* Newton iterations on the model's own Jacobian (pinocchio's frame Jacobian of the error model at
  the model's joint configuration, taken with respect to the commanded joints; the effects' slow
  dependence on the commanded angle - a joint map's slope, a gravity torque's change - is left out
  of the Jacobian and caught by the next iteration, the prediction itself is always the full model);
* the position is matched exactly (first priority, minimum-norm); within the joint motions that
  leave it, the flange keeps the program's orientation (the nominal orientation at ``q``) in the
  directions the model determines (:func:`held_orientation`: no parameter direction the fit's
  measurements could not see, and no parameter left at nominal, turns the flange about them; with
  one SMR and a fitted tool offset, none) (second priority, least squares with a small Tikhonov term on the whole
  correction, :data:`ORIENTATION_DAMPING`, so that near a wrist singularity the correction stays
  small); what is left (a redundant arm's self-motion) is not used: the smallest correction;
* a row outside the joint ranges the model was fitted on, whose correction exceeds the largest one
  allowed, or whose iteration does not reach the point is left as given and says why.

Pure: arrays in, arrays out; the command (``pipeline.cli.deploy``) reads and writes the files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.se3 import rotation_vectors
from ..core.units import REFERENCE_TEMPERATURE_C
from ..robot.model.design import Design
from ..robot.arm.effects import RobotData
from ..robot.arm.kinematics import build_error_model, build_model, gravity_torques, placements, pose_jacobians
from ..robot.model.predict import outside_range
from ..robot.model.rigid import secondary_joints

#: A row is ``ok`` when the model's prediction at its corrected commands is within this of the point (um).
RESIDUAL_TOL_UM = 1.0
#: A joint step below this (deg, 3.6e-5 arcsec) ends the iteration of a row.
STEP_DONE_DEG = 1e-8
#: Tikhonov weight (rad of flange rotation per rad of correction) of the orientation stage: joint
#: motion directions that turn the flange less than this are not used to keep the orientation.
ORIENTATION_DAMPING = 1e-3
#: A flange rotation direction is determined by the model unless some direction of its parameters that
#: the measurements did not determine turns the flange about it by more than this (rad per unit of that
#: direction: one typical size of each parameter for what no measurement could see, one internal unit,
#: a mrad or a mm, for a parameter left at nominal). 1e-6 rad = 0.2 arcsec: a hundredth of a parameter's
#: typical size (100 arcsec) in flange rotation is not an orientation the correction must leave alone.
UNSEEN_ROTATION_RAD = 1e-6
#: Newton iterations at most (typically 3-4 reach 1e-6 um).
MAX_ITER = 20
#: Default largest correction of any joint (deg), as ``robot map-joints``.
MAX_CORRECTION_DEG = 0.5

OK, OUTSIDE, TOO_LARGE, NO_SOLUTION = "ok", "outside_sampled_range", "correction_too_large", "no_solution"


@dataclass
class Correction:
    """Result of :func:`correct_commands` for n rows of an N-joint robot.

    Attributes
    ----------
    q_deg : ndarray, shape (n, N), deg
        Corrected commands (the given ones where ``status != "ok"``).
    dq_arcsec : ndarray, shape (n, N), arcsec
        Corrected - given.
    xyz_mm : ndarray, shape (n, 3), mm
        Nominal kinematics of the corrected commands (the Cartesian target for a controller).
    residual_um : ndarray, shape (n,), um
        Distance between the model's prediction at ``q_deg`` and the point to reach.
    orientation_arcsec : ndarray, shape (n,), arcsec
        Angle between the model's flange orientation at ``q_deg`` and the program's.
    iterations : ndarray, shape (n,), int
    status : ndarray of str, shape (n,)
        ``ok``, ``outside_sampled_range``, ``correction_too_large`` or ``no_solution``.
    reason : ndarray of str, shape (n,)
        Why a row was left as given ('' when ok; for an ok row corrected in position alone, why its
        orientation was not held).
    dirs : ndarray, shape (n, N), int
        Approach directions the correction assumed (given, or from the visiting order).
    orientation_held : ndarray of str, shape (n,)
        The flange rotation directions the correction kept as the program has them (the ones the
        measurements determine, :func:`held_orientation`); '' where the row was left as given.
    u95_mm : ndarray, shape (n,), mm, or None
        The radius about the model's prediction at ``q_deg`` within which the robot lands with 95 %
        probability (contract section 14, :func:`pipeline.robot.model.uncertainty.u95`): for an ``ok``
        row, about the point to reach; for a row left as given, about where the model puts the given
        commands (``model_residual_um`` from the point). None when the model states no uncertainty.
    """

    q_deg: np.ndarray
    dq_arcsec: np.ndarray
    xyz_mm: np.ndarray
    residual_um: np.ndarray
    orientation_arcsec: np.ndarray
    iterations: np.ndarray
    status: np.ndarray
    reason: np.ndarray
    dirs: np.ndarray = None
    orientation_held: np.ndarray = None
    u95_mm: np.ndarray = None
    u95_arcsec: np.ndarray = None    # (n,) arcsec: the probe frame's 95 % angle (a model fitted on orientations)

    def counts(self) -> dict:
        """Rows per status."""
        return {s: int(np.sum(self.status == s)) for s in (OK, OUTSIDE, TOO_LARGE, NO_SOLUTION)}


class ModelKinematics:
    """The fitted model's prediction and Jacobian at commanded joint values (built once per model).

    Parameters
    ----------
    robot : Robot
    model : RobotErrorModel
        Fitted (``coef_``, ``effects_``), e.g. from :func:`pipeline.robot.model.predict.load_model_document`.
    """

    def __init__(self, robot, model):
        self.robot = robot
        self.model = model

    def _built(self):
        if not hasattr(self, "error_model_"):
            self.error_model_, self.index_ = build_error_model(self.robot)
            self.plain_ = build_model(self.robot)
        return self

    def data(self, q_deg, dirs, payload_kg, temperature_c) -> RobotData:
        """The model's view of commanded poses: gravity torques of the commanded pose and payload (N m)."""
        self._built()
        q = np.asarray(q_deg, float)
        tau = gravity_torques(self.robot, q, payload_kg, self.plain_)
        return RobotData(q, np.asarray(dirs, int), np.asarray(payload_kg, float), np.asarray(temperature_c, float),
                         tau, self.robot.lower_deg, self.robot.upper_deg)

    def configurations(self, q_deg, dirs, payload_kg, temperature_c) -> np.ndarray:
        """Error-model configurations (n, nq) of commanded poses: every effect applied."""
        self._built()
        d = Design(self.robot, list(getattr(self.model, "effects_", self.model.effects)),
                   self.data(q_deg, dirs, payload_kg, temperature_c), (self.error_model_, self.index_))
        return d.configurations(self.model.coef_)

    def pose(self, q_deg, dirs, payload_kg, temperature_c):
        """Model flange rotation (n, 3, 3), SMR position (n, 3) mm and the 6-row Jacobian of the SMR
        with respect to the commanded joints (n, 6, N): linear mm/rad, angular rad/rad, world-aligned."""
        Q = self.configurations(q_deg, dirs, payload_kg, temperature_c)
        R, P, J = pose_jacobians(self.error_model_, Q, "smr")
        return R, P, J[:, :, self.index_.joints]

    def unseen_rotations(self, q_deg, dirs, payload_kg, temperature_c) -> np.ndarray:
        """How the model's flange turns along each direction of its parameters that the fit's
        measurements did not determine (:meth:`pipeline.robot.model.estimator.RobotErrorModel.undetermined`),
        at commanded poses: shape (n, 3, m), rad per unit of the direction, world-aligned."""
        self._built()
        D = self.model.undetermined() if hasattr(self.model, "undetermined") else np.zeros((0, 0))
        n = len(np.atleast_2d(q_deg))
        if D.size == 0:
            return np.zeros((n, 3, 0))
        d = Design(self.robot, list(getattr(self.model, "effects_", self.model.effects)),
                   self.data(q_deg, dirs, payload_kg, temperature_c), (self.error_model_, self.index_))
        _, _, J = pose_jacobians(self.error_model_, d.configurations(self.model.coef_), "smr")
        Jx = d.parameter_jacobian(J[:, 3:])   # rad per unit
        return Jx @ D

    def predict(self, q_deg, dirs, payload_kg, temperature_c) -> np.ndarray:
        """Model SMR positions (n, 3) mm."""
        return self.pose(q_deg, dirs, payload_kg, temperature_c)[1]

    def nominal(self, q_deg):
        """Nominal flange rotation (n, 3, 3) and SMR position (n, 3) mm of commanded joints."""
        self._built()
        return placements(self.plain_, np.deg2rad(np.asarray(q_deg, float)), "smr")


def held_orientation(rot_unseen, tol_rad: float = UNSEEN_ROTATION_RAD):
    """The flange rotation directions the model determines, per row.

    Parameters
    ----------
    rot_unseen : ndarray, shape (n, 3, m)
        Flange rotation along each undetermined parameter direction (:meth:`ModelKinematics.unseen_rotations`).

    Returns
    -------
    W : ndarray, shape (n, 3, 3)
        Projector on the determined rotation directions (world-aligned).
    held : ndarray of str, shape (n,)
        In words: ``all``, ``none``, ``all but about (ux uy uz)`` or ``about (hx hy hz) only`` (unit
        axes in the robot base frame).
    """
    n = rot_unseen.shape[0]
    W = np.repeat(np.eye(3)[None], n, axis=0)
    held = np.full(n, "all", dtype=object)
    if rot_unseen.shape[2] == 0:
        return W, held
    U, sv, _ = np.linalg.svd(rot_unseen, full_matrices=True)
    for k in range(n):
        r = int(np.sum(sv[k] > tol_rad))
        Uk = U[k, :, :r]
        W[k] = np.eye(3) - Uk @ Uk.T

        def axis(v):
            v = v * (1.0 if v[np.argmax(np.abs(v))] > 0 else -1.0)
            return "(" + " ".join(f"{x:.3f}" for x in v + 0.0) + ")"
        held[k] = {0: "all", 3: "none"}.get(r) or (f"all but about {axis(U[k, :, 0])}" if r == 1
                                                  else f"about {axis(U[k, :, 2])} only")
    return W, held


def _prioritised_step(J, e_pos, e_rot, dq_so_far=None, damping=ORIENTATION_DAMPING, W=None):
    """Joint step (rad): position first (minimum norm), orientation in what is left (batched).

    The orientation is kept by the joint motions that leave the position alone, in the least-squares
    sense with a small Tikhonov term on the whole correction (``damping``, rad per rad): where the
    wrist is near a singularity, turning the program's orientation back would take large opposite
    motions of two joints for a few arcseconds of flange rotation, and the correction stays small
    instead. Iterated, the steps converge to that compromise (a Gauss-Newton fixed point).

    Parameters
    ----------
    J : ndarray, shape (n, 6, N)
        Linear (mm/rad) and angular (rad/rad) Jacobian rows.
    e_pos : ndarray, shape (n, 3), mm
    e_rot : ndarray, shape (n, 3), rad (world-aligned rotation vector)
    dq_so_far : ndarray, shape (n, N), rad, optional
        Correction already made (the Tikhonov term acts on the total).
    W : ndarray, shape (n, 3, 3), optional
        Projector on the rotation directions to hold (:func:`held_orientation`); the others are not
        an aim, and the joint motions that only turn the flange about them are not used (the
        Tikhonov term keeps the correction there the smallest). Default: all directions.
    """
    Jp, Jr = J[:, :3], J[:, 3:]
    if W is not None:
        Jr = W @ Jr
        e_rot = np.einsum("nij,nj->ni", W, e_rot)
    Jp_pinv = np.linalg.pinv(Jp, rcond=1e-10)
    dq1 = np.einsum("nij,nj->ni", Jp_pinv, e_pos)
    n, _, N = J.shape
    Np = np.eye(N)[None] - Jp_pinv @ Jp
    A = Jr @ Np
    rest = e_rot - np.einsum("nij,nj->ni", Jr, dq1)
    total = dq1 if dq_so_far is None else dq_so_far + dq1
    # [A; lambda Np] z = [rest; -lambda Np total], solved through the normal equations (batched)
    M = np.transpose(A, (0, 2, 1)) @ A + damping ** 2 * Np
    b = np.einsum("nji,nj->ni", A, rest) - damping ** 2 * np.einsum("nij,nj->ni", Np, total)
    z = np.einsum("nij,nj->ni", np.linalg.pinv(M, rcond=1e-12, hermitian=True), b)
    return dq1 + np.einsum("nij,nj->ni", Np, z)


#: two joint axes closer than this (deg apart, and their lines this close, mm) make a singularity
SINGULAR_DEG = 2.0
SINGULAR_MM = 1.0
#: a spherical wrist's point this close to joint 1's axis (mm) is the shoulder singularity
SHOULDER_MM = 50.0


def singularity(robot, q_deg) -> str:
    """What singularity the nominal arm is at or near at ``q_deg`` (N,) deg: two joints turning about
    (nearly) the same line, e.g. joints 4 and 6 at joint 5 = 0, the wrist singularity; a six-joint arm's
    elbow stretched out or folded back (a spherical wrist; joints 2 and 3 parallel, the wrist point within
    :data:`SINGULAR_DEG` of the line through their axes); its shoulder (the wrist point within
    :data:`SHOULDER_MM` of joint 1's axis); any other pose where the joints move the flange in fewer than six
    directions (:func:`_rank_lost`: a UR's, whose wrist axes do not meet); "" when none.

    Parameters
    ----------
    robot : Robot
    q_deg : array_like, shape (N,), deg
    """
    import pinocchio as pin

    model = build_model(robot)
    data = model.createData()
    pin.forwardKinematics(model, data, np.deg2rad(np.asarray(q_deg, float)))
    n = robot.n_joints
    axes = [(data.oMi[i + 1].translation * 1000.0, data.oMi[i + 1].rotation[:, 2]) for i in range(n)]
    for i in range(n):
        for j in range(i + 1, n):
            (p, u), (r, v) = axes[i], axes[j]
            c = np.cross(u, v)
            apart = float(np.rad2deg(np.arcsin(min(1.0, np.linalg.norm(c)))))
            if apart > SINGULAR_DEG:
                continue
            w = r - p
            dist = (abs(w @ c) / np.linalg.norm(c) if np.linalg.norm(c) > 1e-9
                    else float(np.linalg.norm(w - (w @ u) * u)))
            if dist > SINGULAR_MM:
                continue
            pair = f"joints {i + 1} and {j + 1} turn about nearly the same axis ({apart:.3f} deg apart)"
            if i == n - 3 and j == n - 1:
                return (f"the wrist singularity: at joint {j} = {float(q_deg[j - 1]):+.3f} deg {pair}, so a turn about "
                        "it is split between them arbitrarily")
            return f"a singularity: {pair}, so a turn about it is split between them arbitrarily"
    if n == 6 and _spherical_wrist(axes[3:]):
        # the elbow: joints 2 and 3 parallel and the wrist point (where the wrist's three axes meet) on the
        # line through them - the arm stretched out or folded back
        (p2, u2), (p3, u3), (w, _) = axes[1], axes[2], axes[4]
        if np.rad2deg(np.arcsin(min(1.0, np.linalg.norm(np.cross(u2, u3))))) <= SINGULAR_DEG:
            a, b = p3 - p2, w - p3
            a, b = a - (a @ u3) * u3, b - (b @ u3) * u3
            if np.linalg.norm(a) > SINGULAR_MM and np.linalg.norm(b) > SINGULAR_MM:
                bend = float(np.rad2deg(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)))
                off = min(bend, 180.0 - bend)
                if off <= SINGULAR_DEG:
                    how = "stretched out" if bend < 90.0 else "folded back"
                    return (f"the elbow singularity: at joint 3 = {float(q_deg[2]):+.3f} deg the arm is {how}, the "
                            f"wrist point {off:.3f} deg off the line through joints 2 and 3, so it cannot move along "
                            "that line")
        # the shoulder: the wrist point on (near) joint 1's axis, which then hardly moves it
        (p1, u1), w = axes[0], axes[4][0]
        off_mm = float(np.linalg.norm(np.cross(w - p1, u1)))
        if off_mm <= SHOULDER_MM:
            return (f"the shoulder singularity: the wrist point is {off_mm:.1f} mm from joint 1's axis, so joint 1 "
                    "hardly moves it and a sideways correction takes a large turn of joint 1")
    return _rank_lost(axes, data.oMi[n].translation * 1000.0)


#: the flange's motions of a pose (each joint's, lengths over the arm's reach there) span fewer than six
#: directions when a singular value is below this share of the largest (:func:`_rank_lost`)
RANK_RTOL = 1e-3


def _rank_lost(axes, flange_mm) -> str:
    """Any other singular pose (e.g. a UR's, whose wrist axes do not meet: joints 2, 3, 4 and 6 parallel at joint
    5 = 0): the joints' motions of the flange, ``[(point (3,) mm, unit direction (3,)), ...]`` about
    ``flange_mm`` (3,), span fewer than the six (three for fewer joints) directions; "" when they span them all."""
    f = np.asarray(flange_mm, float)
    reach = max(max(float(np.linalg.norm(f - p)) for p, _ in axes), 1.0)
    J = np.array([np.concatenate([np.cross(u, f - p) / reach, u]) for p, u in axes]).T      # (6, N)
    s = np.linalg.svd(J, compute_uv=False)
    full = min(6, len(axes))
    rank = int((s > RANK_RTOL * s[0]).sum())
    if rank >= full:
        return ""
    groups: list[list[int]] = []          # joints (0-based) whose axes are parallel within SINGULAR_DEG
    for i, (_, u) in enumerate(axes):
        for g in groups:
            if np.linalg.norm(np.cross(axes[g[0]][1], u)) <= np.sin(np.deg2rad(SINGULAR_DEG)):
                g.append(i)
                break
        else:
            groups.append([i])
    sets = [", ".join(str(j + 1) for j in g[:-1]) + f" and {g[-1] + 1}" for g in groups if len(g) > 1]
    said = (f"joints {sets[0]} turn about parallel axes" + "".join(f", and joints {t}" for t in sets[1:])) if sets else ""
    return (f"at or near a singular pose: the joints move the flange in only {rank} of {full} directions here"
            + (f" ({said})" if said else "") + ", so a correction along the others is not determined")


def _spherical_wrist(axes) -> bool:
    """Whether three joint axes ``[(point (3,) mm, unit direction (3,)), ...]`` meet at joint 5's point
    (each within :data:`SINGULAR_MM` of it)."""
    w = axes[1][0]
    return all(float(np.linalg.norm(np.cross(w - p, u))) <= SINGULAR_MM for p, u in axes)


def correct_recorded(kin: ModelKinematics, q_deg, *args, **kwargs) -> Correction:
    """:func:`correct_commands` on the controller's own angles: a robot with coupled joints (robot.toml's
    ``[coupling]``, a FANUC's J2/J3 interaction) is corrected on the angles its kinematics take, and the
    corrected commands (``q_deg``, ``dq_arcsec``) are written back in the controller's angles; without
    coupling it is :func:`correct_commands`.

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
        The program's joint values as the controller takes them.
    """
    robot = kin.robot
    if not robot.coupling:
        return correct_commands(kin, q_deg, *args, **kwargs)
    given = np.atleast_2d(np.asarray(q_deg, float))
    res = correct_commands(kin, robot.kinematic_angles(given), *args, **kwargs)
    q = robot.recorded_angles(res.q_deg)
    left = res.status != OK
    q[left] = given[left]
    res.q_deg, res.dq_arcsec = q, (q - given) * 3600.0
    return res


def correct_commands(kin: ModelKinematics, q_deg, target_mm=None, dirs=None, payload_kg=None, temperature_c=None,
                     sampled: dict | None = None, max_correction_deg: float = MAX_CORRECTION_DEG,
                     tol_um: float = RESIDUAL_TOL_UM, max_iter: int = MAX_ITER, target_R=None,
                     stated: dict | None = None, hold_orientation: bool = True) -> Correction:
    """Commands that make the fitted model reach the points (see the module docstring).

    Parameters
    ----------
    kin : ModelKinematics
    q_deg : ndarray, shape (n, N), deg
        The program's nominal joint values, in visiting order.
    target_mm : ndarray, shape (n, 3), mm, optional
        Points to reach in the robot base frame; NaN rows or None: the nominal kinematics of ``q_deg``.
    dirs : ndarray, shape (n, N), int (+1/-1), optional
        Sign of each joint's last motion (backlash); None: from the visiting order of ``q_deg``.
    payload_kg : ndarray, shape (n,), kg, optional (default 0)
    temperature_c : ndarray, shape (n,), degC, optional (default 20)
    sampled : dict, optional
        ``{"lower_deg": [N], "upper_deg": [N]}``: joint ranges the model was fitted on.
    max_correction_deg : float, deg
        Rows needing a larger correction of any joint are left as given.
    tol_um : float, um
        Largest model residual of an ``ok`` row.
    target_R : ndarray, shape (n, 3, 3), optional
        The probe (tool) frame to reach, robot base frame (a 6-DoF model holds it where the measurements
        determine it); NaN rows or None: the nominal kinematics' frame at ``q_deg``.
    stated : dict, optional
        The model's stated uncertainty (:func:`pipeline.robot.model.uncertainty.load_prediction`): then
        each row has its ``u95_mm`` at the commands written (``sampled`` needed).
    hold_orientation : bool
        Hold the orientation where the measurements determine it (default). A row whose correction
        would exceed ``max_correction_deg`` to hold it (near a wrist singularity, turning the frame back
        takes large opposite motions of two joints) is corrected in position alone when that stays
        within the limit: ``orientation_held`` says ``none`` there, ``reason`` why.
    """
    from ..robot.arm.kinematics import directions_from_sequence

    q0 = np.atleast_2d(np.asarray(q_deg, float))
    n, nj = q0.shape
    dirs = directions_from_sequence(q0) if dirs is None else np.asarray(dirs, int)
    payload = np.zeros(n) if payload_kg is None else np.asarray(payload_kg, float)
    temp = np.full(n, REFERENCE_TEMPERATURE_C) if temperature_c is None else np.asarray(temperature_c, float)
    R_nom, P_nom = kin.nominal(q0)
    if target_R is not None:
        tr = np.asarray(target_R, float)
        given = np.all(np.isfinite(tr.reshape(len(tr), -1)), axis=1)
        R_nom = R_nom.copy()
        R_nom[given] = tr[given]
    target = P_nom.copy()
    if target_mm is not None:
        t = np.asarray(target_mm, float)
        given = np.all(np.isfinite(t), axis=1)
        target[given] = t[given]
    status = np.full(n, OK, dtype=object)
    reason = np.full(n, "", dtype=object)
    if sampled is not None:
        out = outside_range(q0, sampled)
        lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
        for k in np.flatnonzero(out):
            j = int(np.argmax(np.maximum(lo - q0[k], q0[k] - hi)))
            status[k] = OUTSIDE
            reason[k] = (f"joint {j + 1} at {q0[k, j]:.3f} deg is outside the range the model was fitted on "
                         f"({lo[j]:.3f} to {hi[j]:.3f} deg)")
    q = q0.copy()
    iters = np.zeros(n, int)
    active = status == OK
    # the orientation is held only in the directions the measurements determine (at the given commands;
    # the correction is small)
    W = np.repeat(np.eye(3)[None], n, axis=0)
    held = np.full(n, "", dtype=object)
    if active.any() and not hold_orientation:
        W[:] = 0.0
        held[active] = "none"
    elif active.any():
        a = np.flatnonzero(active)
        W[a], held[a] = held_orientation(kin.unseen_rotations(q0[a], dirs[a], payload[a], temp[a]))
    res = np.full(n, np.inf)
    for it in range(max_iter + 1):
        idx = np.flatnonzero(active)
        if not idx.size:
            break
        R, P, J = kin.pose(q[idx], dirs[idx], payload[idx], temp[idx])
        e_pos = target[idx] - P
        res[idx] = np.linalg.norm(e_pos, axis=1) * 1000.0
        e_rot = rotation_vectors(R_nom[idx] @ np.transpose(R, (0, 2, 1)))
        if it == max_iter:
            break
        step = np.rad2deg(_prioritised_step(J, e_pos, e_rot, np.deg2rad(q[idx] - q0[idx]), W=W[idx]))
        bad = ~np.all(np.isfinite(step), axis=1) | (np.abs(step).max(axis=1) > 45.0)
        # a row is done when its position is a thousand times inside the tolerance and the next step
        # would move no joint by more than STEP_DONE_DEG (the orientation has converged as far as it can)
        done = (res[idx] <= 1e-3 * tol_um) & (np.abs(step).max(axis=1) <= STEP_DONE_DEG)
        move = ~done & ~bad
        q[idx[move]] += step[move]
        iters[idx[move]] += 1
        active[idx[done | bad]] = False
    # final residual and orientation of every solved row
    solved = np.flatnonzero(status == OK)
    orient = np.zeros(n)
    if solved.size:
        R, P, _ = kin.pose(q[solved], dirs[solved], payload[solved], temp[solved])
        res[solved] = np.linalg.norm(target[solved] - P, axis=1) * 1000.0
        rv = rotation_vectors(R_nom[solved] @ np.transpose(R, (0, 2, 1)))
        orient[solved] = np.rad2deg(np.linalg.norm(np.einsum("nij,nj->ni", W[solved], rv), axis=1)) * 3600.0
    dq = q - q0
    for k in solved:
        if not np.isfinite(res[k]) or res[k] > tol_um:
            status[k] = NO_SOLUTION
            reason[k] = (f"the model does not reach the point: {res[k]:.3g} um left after {iters[k]} iterations "
                         f"(limit {tol_um:g} um)")
            near = singularity(kin.robot, q0[k])
            if near:
                reason[k] += f" ({near})"
        elif np.abs(dq[k]).max() > max_correction_deg:
            j = int(np.argmax(np.abs(dq[k])))
            status[k] = TOO_LARGE
            reason[k] = (f"joint {j + 1} would need {dq[k, j]:+.3f} deg, beyond --max-correction-deg "
                         f"{max_correction_deg:g}")
            near = singularity(kin.robot, q0[k])
            if near:
                reason[k] += f" ({near})"
    big = np.flatnonzero((status == TOO_LARGE) & (held != "none"))
    if hold_orientation and big.size:
        # the position alone, where holding the orientation too would take more than the limit
        tr = None if target_R is None else np.asarray(target_R, float)[big]
        alt = correct_commands(kin, q0[big], target[big], dirs[big], payload[big], temp[big], sampled,
                               max_correction_deg, tol_um, max_iter, tr, None, hold_orientation=False)
        good = alt.status == OK
        k = big[good]
        q[k], dq[k] = alt.q_deg[good], alt.dq_arcsec[good] / 3600.0
        res[k], orient[k], iters[k] = alt.residual_um[good], alt.orientation_arcsec[good], alt.iterations[good]
        status[k], held[k] = OK, "none"
        reason[k] = [f"orientation not held: {r}" for r in reason[k]]
    left = status != OK
    q[left] = q0[left]
    dq[left] = 0.0
    if left.any():
        # what the model says of the given commands where the row was left as given
        P = kin.predict(q0[left], dirs[left], payload[left], temp[left])
        res[left] = np.linalg.norm(target[left] - P, axis=1) * 1000.0
        orient[left] = np.nan
        held[left] = ""
    _, xyz = kin.nominal(q)
    u95_mm = u95_arcsec = None
    if stated is not None and sampled is not None:
        from ..robot.model.uncertainty import u95

        u = u95(kin.model, kin.data(q, dirs, payload, temp), stated, sampled)
        u95_mm = u["u95_mm"]
        u95_arcsec = u.get("u95_arcsec")
    return Correction(q, dq * 3600.0, xyz, res, orient, iters, status.astype(str), reason.astype(str), dirs,
                      held.astype(str), u95_mm, u95_arcsec)


def angle_mismatch(sources, closed) -> str:
    """Why a model does not apply to a robot whose joints ``closed`` (1-based) follow their secondary
    encoders in a closed loop and whose other joints run open loop on their commands ('' when it does).

    ``sources``: the fit JSON's ``joint_angles`` (:func:`pipeline.robot.model.rigid.joint_angle_sources`;
    None: every joint commanded). A joint whose model takes a secondary encoder's angle (a grating)
    has its transmission error, compliance and backlash hidden from the model: open loop they are
    all there (docs/speed.md "Measurements behind the code"). A joint whose model
    takes the commanded angle carries those errors in the model: closed loop they are gone.
    """
    sources = list(sources or [])
    sec = secondary_joints(sources)
    open_sec = [j for j in sec if j not in closed]
    if open_sec:
        js = " ".join(map(str, open_sec))
        return (f"the model was fitted on the secondary encoders' angles of joints {js} "
                f"({', '.join(sources[j - 1] for j in open_sec)}), and the program runs them open loop on their "
                f"commands, where their transmission, compliance and backlash are not in the model: give "
                f"--closed-loop-joints {js} if those joints follow their encoders (closed loop), or fit the model "
                "on a campaign without those encoder readings")
    extra = [j for j in closed if j not in sec]
    if extra:
        js = " ".join(map(str, extra))
        return (f"--closed-loop-joints names joint(s) {js}, which the model takes at their commanded angles "
                f"(fitted open loop: their errors are in the model, and a closed loop would remove them twice); "
                f"name only joints the model was fitted on encoders of ({' '.join(map(str, sec)) or 'none'})")
    return ""
