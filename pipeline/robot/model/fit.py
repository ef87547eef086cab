"""A spec's robot model on a campaign: the effects of each stage of the paper's chain, and the
whole model fitted on the sample poses and judged on the held-out targets (``jointcal fit
--campaign``, the fleet's robot units).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ...core.spec import _locate
from ...core.se3 import angle_arcsec
from .estimate import (N_FOLDS, PARALLEL_CV_MIN_POSES, FoldsBeforeWild, cpu_count, cross_validate, effects_estimator,
                       fit_effects, fold_description, heldout_fit)
from ..campaign.ingest import robot_data_sets
from .plausibility import describe_implausible
from . import outliers
from .outliers import WildSearch, describe
from .predict import model_document, outside_calibrated_range, outside_message, outside_range, sampled_range
from .rigid import chain_document, fit_rigid_chain, has_tables
from .uncertainty import largest_relative, uncertainty_document


def check_spec_joints(spec, robot) -> None:
    """Refuse a spec whose effect names a joint the robot does not have (one located line)."""
    for e in spec.effects:
        joints = e.params.get("joints") if isinstance(e.params, dict) else None
        bad = [j for j in (joints or []) if isinstance(j, int) and j > robot.n_joints]
        if bad:
            try:
                text = Path(spec.path).read_text(encoding="utf-8")
                where = _locate(text, rf"^\s*joints\s*=\s*\[[^\]]*\b{bad[0]}\b")
            except OSError:
                where = (None, None)
            raise InputError(spec.path, f"effect '{e.name}': joints = {joints} names joint {bad[0]}; the robot "
                             f"({robot.name}) has {robot.n_joints} joints, 1..{robot.n_joints}", *where)


def stage_effects(spec, stage: str):
    """Effects of a stage: ``[model] kinematic_effects`` / ``feedback_effects`` name them;
    by default the kinematic stage takes every effect except ``chebyshev`` and the feedback
    stage the ``chebyshev`` effect."""
    key = f"{stage}_effects"
    names = spec.model.get(key)
    if names is None:
        return [e for e in spec.effects if (e.name == "chebyshev") == (stage == "feedback")]
    missing = [n for n in names if spec.effect(n) is None]
    if missing:
        text = Path(spec.path).read_text(encoding="utf-8")
        raise InputError(spec.path, f"{key} names {missing[0]!r}, which has no [[effect]] table",
                         *_locate(text, rf"^\s*{key}\s*="))
    return [e for e in spec.effects if e.name in names]


def unstaged_effects(spec) -> list[str]:
    """Names of the spec's effects that neither stage of the paper's chain takes (``[model]
    kinematic_effects`` / ``feedback_effects``; ``jointcal fit`` and ``diagnose`` take every effect)."""
    staged = {id(e) for stage in ("kinematic", "feedback") for e in stage_effects(spec, stage)}
    return list(dict.fromkeys(e.name for e in spec.effects if id(e) not in staged))


def _silent(message: str) -> None:
    pass


def fit_campaign(campaign, spec, keep_outliers: bool = False, warn=_silent, orientation: bool = True,
                 progress=_silent) -> dict:
    """``jointcal fit --campaign``: :func:`robot_fit_result` of a robot campaign folder, its wild
    measurements named and left out (:mod:`pipeline.robot.model.outliers`) unless ``keep_outliers``.

    ``warn`` receives each console line as it is found (target poses outside the sampled joint
    ranges, the wild poses); ``progress`` what a large campaign's fit is doing (stderr lines). The result has no provenance (the caller hashes the files).
    """
    spec.require_kind("robot", campaign)
    robot, (sample, target), frame_info = robot_data_sets(campaign, ("sample",), ("target",), with_frame=True)
    outside = outside_calibrated_range(sample.q_deg, target.q_deg, target.point_id) if sample.n and target.n else []
    if outside:
        warn(f"warning: {outside_message(outside, worst=True)}")
    check_spec_joints(spec, robot)
    # on a large campaign the wild search runs in a forked process while the model is fitted on every sample
    # pose (robot_fit_result), then taken to the poses kept
    wild = WildSearch(robot, list(spec.effects), sample, target, campaign, keep_outliers)
    return robot_fit_result(campaign, spec, (robot, sample, target, frame_info), wild, orientation=orientation,
                            warn=warn, progress=progress)


def fitted_before_wild(effects, sample, orientation: bool = True) -> bool:
    """Whether :func:`robot_fit_result` fits the model on every sample pose, wild or not, and then takes it to
    the poses kept by Gauss-Newton steps (:meth:`~pipeline.robot.model.estimator.RobotErrorModel.refit_without`):
    on :data:`~pipeline.robot.model.outliers.BACKGROUND_MIN_POSES` sample poses or more, for a model of the
    effects on the whole robot (geometry, base, tool, thermal: nothing prepared from the poses' joint ranges,
    no nested model), positions or positions and orientations weighed by variance components. The fit then
    runs beside the wild search; a few poses of thousands left out move it by little."""
    return (sample.n >= outliers.BACKGROUND_MIN_POSES and bool(effects)
            and all(not getattr(e, "per_joint", True) and e.name != "chebyshev" for e in effects)
            and (orientation or not sample.has_orientation))


def robot_fit_result(campaign, spec, loaded=None, wild=None, orientation: bool = True, warn=_silent,
                     progress=_silent) -> dict:
    """The spec's whole model fitted on a campaign's sample poses, judged on its held-out targets.

    Pure apart from reading the campaign: returns the JSON-ready dict ``jointcal fit`` writes
    (held-out error before/after in mm, the 5-fold cross-validated RMS over the sample poses
    that ``jointcal diagnose`` ranks effects by, and the fitted model as ``jointcal predict``
    reads it: robot, effects, every parameter with its unit and why it was left at nominal if it
    was, the sampled joint ranges, the tracker-to-base transform). ``loaded``: the campaign
    already read, ``(robot, sample, target)`` or ``(robot, sample, target, frame_info)``.
    ``wild``: the campaign's wild poses (:func:`pipeline.robot.model.outliers.find_wild`, or a
    :class:`~pipeline.robot.model.outliers.WildSearch` begun), left out of the fit, the cross-validation and
    the held-out errors (given with them beside, ``heldout_with_outliers``); ``warn`` receives the line
    naming them, ``progress`` what the fit of a large campaign is doing. Where :func:`fitted_before_wild`, the model is fitted on every sample pose first and taken
    to the poses kept by Gauss-Newton steps.
    ``orientation``: on a 6-DoF campaign, fit the orientations too (contract section 13; False: the
    positions alone, the probe's mounting then registered on the orientations). How positions and
    orientations were weighed is ``weighting``; held-out orientation errors are in ``heldout``.
    """
    frame_info = None
    if loaded is None:
        robot, (sample, target), frame_info = robot_data_sets(campaign, ("sample",), ("target",), with_frame=True)
    else:
        robot, sample, target, *rest = loaded
        frame_info = rest[0] if rest else None
    check_spec_joints(spec, robot)
    effects = list(spec.effects)
    target_all, sample_all = target, sample
    first = folds = None
    if wild is not None and sample.n and fitted_before_wild(effects, sample, orientation):
        first, folds, steps = _fit_before_wild(robot, effects, sample, wild, orientation, progress)
    if isinstance(wild, WildSearch):
        wild = wild.result()
        if describe(wild):
            warn(describe(wild))
    if wild is not None:
        sample, target = wild.clean(sample, target)
    if sample.n == 0:
        raise InputError(Path(campaign) / "poses.csv", "no pose has set = sample: nothing to fit the model on "
                         "(to check a fitted model on these poses, use jointcal predict)", 1, "set")
    out = {"kind": "robot", "campaign": str(campaign), "effects": [e.name for e in effects],
           "spec_lines": [e.spec_lines() for e in effects]}
    model = cv_pending = None
    jobs = cpu_count() if sample.n >= PARALLEL_CV_MIN_POSES else 1
    if first is not None:
        keep = np.ones(sample_all.n, bool) if wild.kept else ~wild.sample
        # the folds stepped (or fitted and stepped) to the kept poses in forked processes, the model here
        progress(f"[{steps}/{steps}] the model and the {N_FOLDS} cross-validation folds taken to the {int(keep.sum())} "
                 "sample poses kept; uncertainty")
        cv_pending = folds.start(keep, jobs)
        model = first.refit_without(sample_all, keep, sample)
        first.release_designs()
        if model is not None:
            model.release_designs()
    from_first = model is not None
    if model is None:
        model = fit_effects(robot, effects, sample, check_nested=True, orientation=orientation)
    if target.n:
        out["heldout"] = heldout_fit(robot, effects, sample, target, model=model)
        rng = sampled_range(sample.q_deg)
        out["heldout"]["outside_sampled_range"] = int(outside_range(target.q_deg, rng).sum())
    if wild is not None:
        out.update(wild.document())
        if target_all.n > target.n:
            out["heldout_with_outliers"] = heldout_fit(robot, effects, sample, target_all, model=model)
            out["heldout_with_outliers"].pop("parameters", None)
    cv = cv_pending() if cv_pending is not None else None
    if cv is not None and from_first:
        # the folds drawn over every sample pose, each fold's model taken to the other folds' kept poses
        described = fold_description(sample) + (f" (drawn over all {sample_all.n}, the {sample_all.n - sample.n} "
                                                 "wild ones in none)" if sample_all.n > sample.n else "")
    else:
        cv = cross_validate(robot, effects, sample, orientation=orientation,
                            orientation_weight=getattr(model, "weight_", None) if orientation else None, jobs=jobs)
        described = fold_description(sample)
    _document(out, robot, effects, model, sample, cv, described, frame_info)
    return out


def _fit_before_wild(robot, effects, sample, wild, orientation, progress):
    """The model fitted on every sample pose (its design kept), and its cross-validation folds (fitted
    beside a wild search that runs): ``(first, folds, steps)``, ``steps`` the progress lines' count."""
    beside = isinstance(wild, WildSearch) and wild.running
    steps = 4 if beside else 2
    progress(f"[1/{steps}] {' + '.join(e.name for e in effects)} on all {sample.n} sample poses"
             + (" (the wild-point search runs beside it)" if beside else ""))
    est = effects_estimator(robot, effects, orientation=orientation)
    est.keep_designs = True       # the steps to the poses kept reuse its design
    first = est.fit(sample)
    first.conflict_, first.nested_ = "", []
    folds = FoldsBeforeWild(robot, effects, sample, orientation, first.weight_, first=first)
    if beside:
        progress(f"[2/4] the {N_FOLDS} cross-validation folds, each on the others' poses")
        folds.fit()                  # while the search runs
        progress("[3/4] waiting for the wild-point search")
    return first, folds, steps


def _document(out: dict, robot, effects, model, sample, cv, described: str, frame_info) -> None:
    """The fit document's cross-validation, model, uncertainty, rigid chains and verdict, added to ``out``
    in the document's order."""
    out["cv_rms_mm"] = cv.rms
    if "orientation" in cv.extra:
        out["cv_orientation_rms_arcsec"] = float(np.sqrt(np.mean(angle_arcsec(cv.extra["orientation"]) ** 2)))
    out["cv_folds"] = described
    if getattr(model, "weighting_", None):
        out["weighting"] = model.weighting_
    out.update(model_document(robot, effects, model, sample.q_deg, frame_info, sample=sample))
    # how sure (contract section 14): each parameter's 1-sigma uncertainty, the pairs that trade, and what
    # predict and correct need for each point's u95_mm
    stated = uncertainty_document(model, sample, cv.residuals, N_FOLDS, cv.extra.get("orientation"))
    for entry, u in zip(out["parameters"], stated["uncertainty"]):
        entry["uncertainty"] = u
    out["correlations"] = stated["correlations"]
    out["largest_relative_uncertainty"] = largest_relative(out["parameters"], skip=stated["penalised"])
    out["prediction_uncertainty"] = stated["prediction"]
    # the rigid chain a URDF or a controller's parameters take: the one nearest the whole model
    chain, info = fit_rigid_chain(robot, model, sample)
    out["rigid_chain"] = chain_document(chain, info, out["payloads_kg"])
    if has_tables(robot, model):
        # and the chain for drives that apply the joint tables (jointcal export --format table)
        chain, info = fit_rigid_chain(robot, model, sample, with_tables=True)
        out["rigid_chain_with_tables"] = chain_document(chain, info, out["payloads_kg"], with_tables=True)
    out["not_identified"] = out["identification"]["fixed"]
    out["converged"] = bool(getattr(model, "converged_", True))
    out["convergence"] = getattr(model, "convergence_", "")
    out["plausible"] = bool(getattr(model, "plausible_", True))
    out["implausible"] = getattr(model, "implausible_", [])
    if getattr(model, "conflict_", ""):
        out["conflict"] = model.conflict_


def fit_problems(result: dict) -> list[str]:
    """Why a fit must not be used (did not converge, or parameters no real robot has); [] if fine."""
    out = []
    if not result.get("converged", True):
        out.append(f"the fit did not converge ({result.get('convergence') or 'no reason given'})")
    if not result.get("plausible", True):
        out.append(f"parameters no real robot has: {describe_implausible(result.get('implausible', []))}")
    if result.get("conflict"):
        out.append(result["conflict"])
    return out
