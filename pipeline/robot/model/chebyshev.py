"""Chebyshev error transfer matrices (the second paper, Eqs. 7-13) and their identification.

The actual kinematics is ``F_a(theta) = T_1 E_1(theta_1) T_2 E_2(theta_2) ... T_n E_n(theta_n)``
(Eq. 7); every error transfer matrix E_i (Eq. 8) carries three translations delta_{i,k} and
three rotations epsilon_{i,k} (k = x, y, z) that are Chebyshev polynomials of order m in the
joint angle mapped to [-1, 1] over the campaign's joint range (Eqs. 9-10):

    epsilon_{i,k} = sum_j lambda^{(i)}_{j,k} c_j(theta~_i),  delta_{i,k} = sum_j gamma^{(i)}_{j,k} c_j(theta~_i)

This is the ``chebyshev`` effect of :mod:`pipeline.robot.arm.effects` (E_i realised as an exact
rigid transform by the error joints of the pinocchio error model; to first order it is the
matrix of Eq. 8). The coefficients are identified on the sample poses by the improved
Levenberg-Marquardt of Eqs. 14-21 (:mod:`pipeline.robot.model.lm`) with the analytic pinocchio Jacobian
(Eq. 13), and by ``scipy.optimize.least_squares`` as a cross-check.

Identifiability: with 6 joints and order 3 there are 144 coefficients, many of them
redundant (a translation along a joint axis is the same whichever link carries it; order-0
terms of neighbouring links overlap). The rank of the scaled Jacobian is reported; the
improved L-M's damping (mu_k, :mod:`pipeline.robot.model.lm`) and scipy's exact trust-region solves keep the
redundant directions where they start (0). Beyond the exact redundancies, many directions
are only weakly identified (relative singular values 1e-4 to 1e-8): fitting them fits noise
and the least-squares problem has no well-defined minimum (scipy's MINPACK keeps lowering the
cost for 10,000+ evaluations with ever larger coefficients). We therefore fix the
coefficients beyond the numerical rank (tolerance :data:`CHEB_RANK_TOL`, chosen at the gap of
the singular values) out by solving in the span of the leading right singular vectors of the
column-scaled Jacobian (truncated SVD, the minimum-norm solution); both solvers then solve the
same well-posed problem and reach the same cost.

Cross-check (issue #10): :func:`identify` reports, and :func:`cross_check_problems` lists, what
makes the result unusable: either solver not converged (iteration limit, never left the start,
not stationary: :mod:`pipeline.robot.model.lm`), costs differing by more than :data:`CROSS_CHECK_RTOL`, or a
fitted coefficient no real robot can have (:data:`pipeline.robot.model.lm.PLAUSIBLE_BOUNDS`).
``jointcal robot chebyshev`` then writes nothing and exits 1.
"""

from __future__ import annotations

from .estimator import RobotErrorModel
from .plausibility import describe_implausible

#: numerical rank tolerance of the Chebyshev identification: the scaled Jacobian's singular
#: values fall from 1e-3.2 to 1e-4 and then trail off to 1e-8 (weakly identified directions that
#: only fit noise) and 1e-16 (exact redundancies); coefficients beyond this rank are fixed at 0.
CHEB_RANK_TOL = 3e-4
LM_DEFAULTS = {"v1": 1.0, "m": 1e-6, "p0": 1e-4, "p1": 0.25, "p2": 0.75, "phi": 1e-5, "max_iter": 100}
#: largest relative difference of the improved L-M's and scipy's costs for the result to be used
CROSS_CHECK_RTOL = 0.01


def chebyshev_estimator(robot, effects, solver="lm", lm_options=None) -> RobotErrorModel:
    """The estimator of a model with Chebyshev terms: solved in the span of the leading singular
    directions of the scaled Jacobian (relative singular value >= CHEB_RANK_TOL). The coefficients
    overlap each other and the MDH parameters; the weak directions only fit noise."""
    return RobotErrorModel(robot, effects, solver=solver, lm_options=lm_options, rank_tol=CHEB_RANK_TOL,
                           reduction="svd")


def identify(robot, data, effects, lm_options: dict | None = None) -> dict:
    """Fit the Chebyshev model with the improved L-M and with scipy; JSON-ready result.

    Parameters
    ----------
    robot : Robot
    data : RobotData
        Sample poses with tracker positions (mm).
    effects : list of RobotEffect (the feedback stage's effects, normally one ``chebyshev``)
    lm_options : dict, optional
        Overrides of :data:`LM_DEFAULTS` (from the spec's ``[model] lm`` table).
    """
    opts = {**LM_DEFAULTS, **(lm_options or {})}
    lm = chebyshev_estimator(robot, effects, "lm", opts).fit(data)
    sp = chebyshev_estimator(robot, effects, "scipy").fit(data)
    ident = lm.identifiability_
    res_lm, res_sp = lm.solver_result_, sp.solver_result_
    return {
        "effects": [e.spec_lines() for e in effects],
        "n_poses": int(data.n), "n_params": ident["n_params"], "rank": ident["rank"],
        "rank_exact": ident["rank_exact"], "rank_tol": CHEB_RANK_TOL,
        "condition_number": ident["condition_number"],
        "condition_number_all": ident["condition_number_all"],
        "exact_redundancies": ident["n_params"] - ident["rank_exact"],
        "directions_left_out": ident["n_params"] - ident["rank"],
        "joint_range_deg": {"lower": data.lower_deg.tolist(), "upper": data.upper_deg.tolist()},
        "lm": {"cost_mm2": res_lm.cost, "iterations": res_lm.n_iter, "function_evaluations": res_lm.n_fev,
               "jacobian_evaluations": res_lm.n_jev, "converged": res_lm.converged, "stop": res_lm.reason,
               "seconds": lm.seconds_, "rms_mm": lm.rms_mm_, "plausible": lm.plausible_, "options": opts,
               "history": res_lm.history},
        "scipy": {"cost_mm2": res_sp.cost, "iterations": res_sp.n_iter, "jacobian_evaluations": res_sp.n_jev,
                  "converged": res_sp.converged, "stop": res_sp.reason, "seconds": sp.seconds_,
                  "rms_mm": sp.rms_mm_, "plausible": sp.plausible_,
                  "method": "least_squares(method='trf', tr_solver='exact')"},
        # the two costs agree to rounding noise (1e-12, different on every CPU): written to 1e-9
        "cost_relative_difference": round(abs(res_lm.cost - res_sp.cost) / max(res_sp.cost, 1e-300), 9),
        "cost_relative_tolerance": CROSS_CHECK_RTOL,
        "implausible": {"lm": lm.implausible_, "scipy": sp.implausible_},
        "parameters": lm.parameters(),
        "parameters_scipy": sp.parameters(),
    }


def cross_check_problems(result: dict) -> list[str]:
    """What makes an :func:`identify` result unusable (empty when the solvers agree and converged)."""
    out = []
    for key, name in (("lm", "the improved L-M"), ("scipy", "scipy")):
        if not result[key]["converged"]:
            out.append(f"{name} did not converge ({result[key]['stop']})")
    rel = result["cost_relative_difference"]
    if not rel <= CROSS_CHECK_RTOL:
        out.append(f"the improved L-M's cost {result['lm']['cost_mm2']:.6g} mm^2 and scipy's "
                   f"{result['scipy']['cost_mm2']:.6g} mm^2 differ by {100 * rel:.3g} % "
                   f"(more than {100 * CROSS_CHECK_RTOL:g} %)")
    for key, name in (("lm", "improved L-M"), ("scipy", "scipy")):
        bad = result["implausible"][key]
        if bad:
            out.append(f"{name} coefficients no real robot has: {describe_implausible(bad)}")
    return out


def model_from_json(robot, effects, result: dict) -> RobotErrorModel:
    """The fitted (improved L-M) model from a ``chebyshev.json`` result."""
    return RobotErrorModel.from_parameters(robot, effects, result["parameters"])
