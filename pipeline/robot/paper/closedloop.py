"""Joint closed-loop feedback (the second paper, Section 2.2-3.1, Eq. 26).

Every 12 ms (the KUKA RSI cycle) the absolute grating of a joint is read, the error
``e(n) = target - reading`` (deg) is formed and a joint correction increment ``u(n)`` is
sent to the controller, which adds it to the joint command:

* rough correction: ``u(n) = 0.002 deg * sign(e(n))`` while ``|e(n)| >= 0.007 deg``;
* fine correction (PD, Eq. 26): ``u(n) = kP e(n) + kD (e(n) - e(n-1))`` with kP = 0.05,
  kD = 0.65.

What the PD output means: ``u(n)`` is an *increment* of the joint command per cycle (RSI
corrections are relative). With a joint that follows its command increments, the error
obeys ``e(n+1) = e(n) - u(n)``, i.e.

    e(n+1) = (1 - kP - kD) e(n) + kD e(n-1)

whose characteristic roots for the paper's gains are z = 0.970 and z = -0.670: both inside
the unit circle, so the loop converges; the dominant root is real and positive, so the
error decays without overshoot (about 3 % per cycle, time constant about 33 cycles =
0.4 s), as the paper wants ("approach the target quickly without overshoot").
:func:`pd_poles` gives the roots for any gains.

The plant (:class:`JointPlant`) is a joint with play: the output lags the motor command by
up to half the backlash, then follows it; the grating reads the output angle (true link
angle) with its resolution. The loop therefore takes up the play in whatever direction the
correction needs - it removes backlash, which open-loop commands cannot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CYCLE_S = 0.012
ROUGH_STEP_DEG = 0.002
ROUGH_LIMIT_DEG = 0.007
KP = 0.05
KD = 0.65


def pd_poles(kp: float = KP, kd: float = KD) -> np.ndarray:
    """Roots of z^2 - (1 - kP - kD) z - kD (error dynamics of the incremental PD loop)."""
    return np.roots([1.0, -(1.0 - kp - kd), -kd])


@dataclass
class JointPlant:
    """Joints with play, driven by command increments (vectorised over joints/poses).

    Attributes
    ----------
    command_deg : ndarray, shape (k,)
        Motor-side joint command.
    play_deg : ndarray, shape (k,)
        Full backlash of each joint.
    state_deg : ndarray, shape (k,)
        Output position of the play element (lags the command by up to play/2).
    offset_deg : ndarray, shape (k,)
        Repeatable output error added to the play output (transmission, compliance).
    resolution_deg : float
        Grating resolution (reading quantum).
    """

    command_deg: np.ndarray
    play_deg: np.ndarray
    state_deg: np.ndarray
    offset_deg: np.ndarray
    resolution_deg: float = 0.0

    def move(self, increment_deg):
        self.command_deg = self.command_deg + increment_deg
        half = self.play_deg / 2
        self.state_deg = np.clip(self.state_deg, self.command_deg - half, self.command_deg + half)

    @property
    def output_deg(self):
        return self.state_deg + self.offset_deg

    def read(self):
        if self.resolution_deg > 0:
            return np.round(self.output_deg / self.resolution_deg) * self.resolution_deg
        return self.output_deg.copy()


def run_loop(plant: JointPlant, target_deg, kp=KP, kd=KD, rough_step=ROUGH_STEP_DEG, rough_limit=ROUGH_LIMIT_DEG,
             tol_deg=2e-5, settle=3, max_cycles=6000, trace=False):
    """Drive every joint of ``plant`` until its grating reads ``target_deg``.

    Parameters
    ----------
    plant : JointPlant (modified in place)
    target_deg : ndarray, shape (k,), deg
    tol_deg : float
        A joint is done after ``settle`` consecutive cycles with |e| < tol.

    Returns
    -------
    dict with ``cycles`` (k,) cycles to finish, ``final_error_deg`` (k,) and, when
    ``trace``, ``error_deg`` of shape (cycles, k) and ``phase`` (0 rough, 1 fine).
    """
    target = np.asarray(target_deg, float)
    k = target.size
    e_prev = None
    done = np.zeros(k, bool)
    calm = np.zeros(k, int)
    cycles = np.full(k, max_cycles)
    fine = np.zeros(k, bool)
    errors, phases = [], []
    for n in range(max_cycles):
        e = target - plant.read()
        if trace:
            errors.append(e.copy())
            phases.append(fine.copy())
        calm = np.where(np.abs(e) < tol_deg, calm + 1, 0)
        newly = ~done & (calm >= settle)
        cycles[newly] = n
        done |= newly
        if done.all():
            break
        fine = fine | (np.abs(e) < rough_limit)
        if e_prev is None:
            e_prev = e.copy()
        pd = kp * e + kd * (e - e_prev)
        u = np.where(fine, pd, rough_step * np.sign(e))
        u = np.where(done, 0.0, u)
        plant.move(u)
        e_prev = np.where(fine, e, e)  # e(n-1) of the next cycle
    out = {"cycles": cycles, "final_error_deg": target - plant.read()}
    if trace:
        out["error_deg"] = np.array(errors)
        out["fine"] = np.array(phases)
    return out
