"""Nominal kinematics of a robot for its controller: forward kinematics, every inverse-kinematics
branch of a pose, and the branch flags a configuration names.

For any serial arm of ``robot.toml`` (contract section 2), not one vendor's closed form:

* forward kinematics and the geometric Jacobian of the flange, batched over many poses in numpy
  (the same chain as pinocchio's :func:`pipeline.robot.arm.kinematics.build_model`; a test compares them);
* inverse kinematics by damped Newton (Levenberg-Marquardt on position and rotation vector) from
  several seeds at once: one per branch of the arm (found once per robot by classifying sampled
  joint values, each turned about joint 1 towards the target), then, where a wanted branch is still
  missing, from a fixed quasi-random set of seeds. The distinct solutions (joint angles taken in
  (-180, 180]) are the branches of the pose; :func:`expand_turns` adds the +-360 deg copies the
  joint ranges allow;
* the three branch flags of a six-joint arm, from its geometry: ``rear`` - the wrist point (origin
  of link frame {4}) behind joint 1's axis (along the x axis of link frame {1}); ``down`` - the wrist
  point below the line through the axes of joints 2 and 3 (elbow down); ``flip`` - joint 5 turned
  negatively from the wrist singularity (axes 4 and 6 parallel), i.e. ``(z4 x z6) . z5 < 0``.

Lengths mm, angles rad inside (deg at the edges, as named).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.se3 import rotation_vectors
from ..robot.arm.kinematics import Robot

#: a Newton solution is accepted within these of the pose (mm, rad)
POS_TOL_MM, ROT_TOL_RAD = 1e-7, 1e-10
MAX_ITER = 60
#: largest joint step of one Newton iteration (rad)
MAX_STEP_RAD = 0.4
#: solutions closer than this (rad, every joint) are the same branch
SAME_RAD = 1e-6


@dataclass(frozen=True)
class Chain:
    """Constants of a robot's chain: joint offsets (N,) rad and link transforms (N, 4, 4) mm."""

    offset: np.ndarray
    link: np.ndarray
    lower: np.ndarray     # (N,) rad
    upper: np.ndarray     # (N,) rad


def chain_of(robot: Robot) -> Chain:
    """The chain of a robot: ``T_i = Rz(q_i + off_i) . Tz(d_i) . Tx(a_i) . Rx(alpha_i) . Ry(beta_i)``."""
    links = []
    for j in robot.joints:
        al, be = np.deg2rad(j.alpha_deg), np.deg2rad(j.beta_deg)
        Rx = np.array([[1, 0, 0], [0, np.cos(al), -np.sin(al)], [0, np.sin(al), np.cos(al)]])
        Ry = np.array([[np.cos(be), 0, np.sin(be)], [0, 1, 0], [-np.sin(be), 0, np.cos(be)]])
        L = np.eye(4)
        L[:3, :3] = Rx @ Ry
        L[:3, 3] = [j.a_mm, 0.0, j.d_mm]
        links.append(L)
    return Chain(np.deg2rad([j.theta_offset_deg for j in robot.joints]), np.array(links),
                 np.deg2rad(robot.lower_deg), np.deg2rad(robot.upper_deg))


def frames(chain: Chain, Q) -> np.ndarray:
    """Link frames {0} .. {N} of joint values.

    Parameters
    ----------
    Q : ndarray, shape (n, N), rad

    Returns
    -------
    ndarray, shape (n, N + 1, 4, 4), mm: frame {i} after ``T_1 ... T_i`` ({0}: the base).
    """
    Q = np.atleast_2d(np.asarray(Q, float))
    n, N = Q.shape
    F = np.empty((n, N + 1, 4, 4))
    F[:, 0] = np.eye(4)
    th = Q + chain.offset
    c, s = np.cos(th), np.sin(th)
    for i in range(N):
        Rz = np.zeros((n, 4, 4))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1] = c[:, i], -s[:, i], s[:, i], c[:, i]
        Rz[:, 2, 2] = Rz[:, 3, 3] = 1.0
        F[:, i + 1] = F[:, i] @ Rz @ chain.link[i]
    return F


def flange(chain: Chain, Q) -> np.ndarray:
    """Flange poses (n, 4, 4) mm of joint values Q (n, N) rad."""
    return frames(chain, Q)[:, -1]


def jacobian(F: np.ndarray) -> np.ndarray:
    """Geometric Jacobian of the flange, world-aligned: rows linear (mm/rad) then angular (rad/rad).

    Parameters
    ----------
    F : ndarray, shape (n, N + 1, 4, 4), from :func:`frames`

    Returns
    -------
    ndarray, shape (n, 6, N)
    """
    z = F[:, :-1, :3, 2]                     # axis of joint i: z of frame {i-1}
    o = F[:, :-1, :3, 3]
    p = F[:, -1, :3, 3]
    lin = np.cross(z, p[:, None, :] - o)
    return np.concatenate([np.transpose(lin, (0, 2, 1)), np.transpose(z, (0, 2, 1))], axis=1)


def _errors(F_end, T):
    e_p = T[:, :3, 3] - F_end[:, :3, 3]
    e_r = rotation_vectors(T[:, :3, :3] @ np.transpose(F_end[:, :3, :3], (0, 2, 1)))
    return e_p, e_r


def newton(chain: Chain, T, Q0, max_iter: int = MAX_ITER):
    """Damped Newton from seeds to flange poses (batched).

    Parameters
    ----------
    T : ndarray, shape (n, 4, 4), mm
    Q0 : ndarray, shape (n, N), rad

    Returns
    -------
    Q : ndarray, shape (n, N), rad
    ok : ndarray, shape (n,), bool: within :data:`POS_TOL_MM` and :data:`ROT_TOL_RAD`
    """
    Q = np.array(Q0, float)
    T = np.asarray(T, float)
    n, N = Q.shape
    ok = np.zeros(n, bool)
    active = np.arange(n)
    for _ in range(max_iter + 1):
        if not active.size:
            break
        F = frames(chain, Q[active])
        e_p, e_r = _errors(F[:, -1], T[active])
        conv = (np.linalg.norm(e_p, axis=1) < POS_TOL_MM) & (np.linalg.norm(e_r, axis=1) < ROT_TOL_RAD)
        ok[active[conv]] = True
        keep = ~conv
        active, F, e_p, e_r = active[keep], F[keep], e_p[keep], e_r[keep]
        if not active.size:
            break
        J = jacobian(F)
        J[:, :3] /= 1000.0                     # metres: position and rotation of the same weight
        e = np.concatenate([e_p / 1000.0, e_r], axis=1)
        lam = 1e-6 + 1e-2 * np.minimum(np.sum(e * e, axis=1), 1.0)
        JJt = J @ np.transpose(J, (0, 2, 1)) + lam[:, None, None] * np.eye(6)[None]
        dq = np.einsum("nji,nj->ni", J, np.linalg.solve(JJt, e[:, :, None])[:, :, 0])
        big = np.abs(dq).max(axis=1, keepdims=True)
        dq *= np.minimum(1.0, MAX_STEP_RAD / np.maximum(big, 1e-300))
        Q[active] += dq
    return Q, ok


def wrap(Q):
    """Angles in (-pi, pi]."""
    return -((-np.asarray(Q, float) + np.pi) % (2 * np.pi) - np.pi)


# ---------------------------------------------------------------------------- branch flags
def flags_from_frames(F: np.ndarray) -> np.ndarray:
    """Branch flags ``(rear, down, flip)`` (n, 3) bool and their margins from link frames (n, 7, 4, 4)."""
    return _flag_values(F) < 0


def _flag_values(F: np.ndarray) -> np.ndarray:
    """Signed flag functions (n, 3): negative = rear / down / flip (see the module docstring)."""
    z0 = F[:, 0, :3, 2]
    x1 = F[:, 1, :3, 0]
    x1 = x1 - np.sum(x1 * z0, axis=1, keepdims=True) * z0
    x1 /= np.maximum(np.linalg.norm(x1, axis=1, keepdims=True), 1e-300)
    pw = F[:, 4, :3, 3]
    o0, o1, o2 = F[:, 0, :3, 3], F[:, 1, :3, 3], F[:, 2, :3, 3]
    front = np.sum((pw - o0) * x1, axis=1)
    y_fwd = np.cross(z0, x1)
    up = np.sum(np.cross(o2 - o1, pw - o2) * y_fwd, axis=1)
    z3, z4, z5 = F[:, 3, :3, 2], F[:, 4, :3, 2], F[:, 5, :3, 2]
    wrist = np.sum(np.cross(z3, z5) * z4, axis=1)
    return np.stack([front, up, wrist], axis=1)


def arm_flags(chain: Chain, Q_deg) -> np.ndarray:
    """Branch flags ``(rear, down, flip)`` of joint values.

    Parameters
    ----------
    Q_deg : ndarray, shape (n, N), deg

    Returns
    -------
    ndarray, shape (n, 3), bool
    """
    return flags_from_frames(frames(chain, np.deg2rad(np.atleast_2d(Q_deg))))


def branch_seeds(chain: Chain, n_samples: int = 4096) -> np.ndarray:
    """One representative joint vector (rad) per branch of the arm (up to 8), far from the
    singularities that separate them: the sampled one with the largest smallest flag margin."""
    rng = np.random.default_rng(20240)
    N = len(chain.offset)
    Q = rng.uniform(-np.pi, np.pi, (n_samples, N))
    F = frames(chain, Q)
    v = _flag_values(F)
    scale = np.maximum(np.abs(v).max(axis=0), 1e-300)
    margin = np.min(np.abs(v) / scale, axis=1)
    code = (v < 0) @ np.array([1, 2, 4])
    out = []
    for c in range(8):
        idx = np.flatnonzero(code == c)
        if idx.size:
            out.append(Q[idx[np.argmax(margin[idx])]])
    return np.array(out)


def _azimuth(p):
    return np.arctan2(p[..., 1], p[..., 0])


def solve_all(chain: Chain, T, seeds=None, extra: int = 0, want=None):
    """Every inverse-kinematics solution found for flange poses.

    Parameters
    ----------
    T : ndarray, shape (n, 4, 4), mm
    seeds : ndarray, shape (k, N), rad, optional
        Branch representatives (default :func:`branch_seeds`); each is turned about joint 1 so that
        its wrist faces the pose's as the representative's faces its own.
    extra : int
        Quasi-random seeds tried as well (for every pose).
    want : ndarray, shape (n, 3) of bool or None rows, optional
        Branch flags wanted per pose: where they are not found, 64 more seeds are tried.

    Returns
    -------
    list of ndarray, shape (m_i, N), rad in (-pi, pi]: the distinct solutions of each pose.
    """
    T = np.asarray(T, float)
    n = len(T)
    N = len(chain.offset)
    seeds = branch_seeds(chain) if seeds is None else np.asarray(seeds, float)
    F_seed = frames(chain, seeds)
    az_seed = _azimuth(F_seed[:, -1, :3, 3])
    az_t = _azimuth(T[:, :3, 3])
    S = np.repeat(seeds[None], n, axis=0)                   # (n, k, N)
    S[:, :, 0] += az_t[:, None] - az_seed[None, :]
    rng = np.random.default_rng(7)
    if extra:
        S = np.concatenate([S, rng.uniform(-np.pi, np.pi, (n, extra, N))], axis=1)
    sols = _run(chain, T, S)
    if want is not None:
        missing = [i for i in range(n) if want[i] is not None
                   and not any(tuple(f) == tuple(want[i]) for f in flags_from_frames(frames(chain, sols[i])))]
        if missing:
            more = rng.uniform(-np.pi, np.pi, (len(missing), 64, N))
            extra_sols = _run(chain, T[missing], more)
            for i, s in zip(missing, extra_sols):
                sols[i] = _dedupe(np.concatenate([sols[i], s]))
    return sols


def _run(chain, T, S):
    n, k, N = S.shape
    Q, ok = newton(chain, np.repeat(T, k, axis=0), S.reshape(n * k, N))
    Q = wrap(Q).reshape(n, k, N)
    ok = ok.reshape(n, k)
    return [_dedupe(Q[i][ok[i]]) for i in range(n)]


def _dedupe(Q):
    out = []
    for q in Q:
        if not any(np.all(np.abs(wrap(q - o)) < SAME_RAD) for o in out):
            out.append(q)
    return np.array(out).reshape(-1, Q.shape[-1] if Q.ndim == 2 else 0) if out else np.zeros((0, Q.shape[-1]))


def expand_turns(chain: Chain, Q) -> np.ndarray:
    """Every copy of solutions (m, N) rad with joints shifted by multiples of 2 pi inside the joint
    ranges (the solutions outside the ranges drop out)."""
    out = []
    for q in np.atleast_2d(Q):
        options = []
        for i, v in enumerate(q):
            ks = np.arange(np.ceil((chain.lower[i] - v) / (2 * np.pi) - 1e-12),
                           np.floor((chain.upper[i] - v) / (2 * np.pi) + 1e-12) + 1)
            options.append(v + 2 * np.pi * ks)
        if any(len(o) == 0 for o in options):
            continue
        grid = np.stack(np.meshgrid(*options, indexing="ij"), axis=-1).reshape(-1, len(q))
        out.append(grid)
    return np.concatenate(out) if out else np.zeros((0, len(chain.offset)))


def solve_branch(chain: Chain, T, want) -> list:
    """The solutions of flange poses on wanted branches.

    Parameters
    ----------
    T : ndarray, shape (n, 4, 4), mm
    want : ndarray, shape (n, 3), bool
        Branch flags ``(rear, down, flip)`` wanted per pose.

    Returns
    -------
    list of ndarray, shape (m_i, N), rad in (-pi, pi]: solutions with the wanted flags (m_i = 0: none found).
    """
    T = np.asarray(T, float)
    want = np.asarray(want, bool).reshape(-1, 3)
    n, N = len(T), len(chain.offset)
    reps = branch_seeds(chain)
    rep_flags = flags_from_frames(frames(chain, reps))
    az_rep = _azimuth(frames(chain, reps)[:, -1, :3, 3])
    az_t = _azimuth(T[:, :3, 3])
    match = np.all(rep_flags[None, :, :] == want[:, None, :], axis=2)           # (n, k)
    pick = np.where(match.any(axis=1), np.argmax(match, axis=1), 0)
    S = reps[pick].copy()
    S[:, 0] += az_t - az_rep[pick]
    Q, ok = newton(chain, T, S)
    Q = wrap(Q)
    good = ok & np.all(flags_from_frames(frames(chain, Q)) == want, axis=1)
    out = [Q[i:i + 1] if good[i] else np.zeros((0, N)) for i in range(n)]
    missing = np.flatnonzero(~good)
    if missing.size:
        rng = np.random.default_rng(7)
        more = _run(chain, T[missing], np.concatenate(
            [np.repeat(reps[None], len(missing), axis=0), rng.uniform(-np.pi, np.pi, (len(missing), 56, N))], axis=1))
        for i, s in zip(missing, more):
            out[i] = _keep(chain, s, want[i])
    return out


def _keep(chain, Q, want):
    if not len(Q):
        return Q
    f = flags_from_frames(frames(chain, Q))
    return Q[np.all(f == want, axis=1)]
