"""``jointcal correct --targets``: a targets file corrected with a fitted robot model (contract section 8).

:func:`correct_targets` is the whole job between reading the inputs and writing the output: the
targets read and checked (:func:`pipeline.correct.targets.read_targets`), every row corrected
(:func:`pipeline.correct.robot.correct_recorded`, on the controller's angles), the corrected program as CSV text
(:func:`pipeline.correct.write.corrected_csv`). The command (``pipeline.cli.deploy``) reads the model,
writes the text and prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..robot.model.rigid import assumptions, model_payload
from ..robot.model.uncertainty import beyond_deg, in_gap, load_prediction
from .robot import Correction, ModelKinematics, correct_recorded
from .targets import Targets, read_targets
from .write import corrected_csv


#: The console names at most this many targets outside the calibrated region one by one (then how many more)
OUTSIDE_NAMED = 20


def outside_region(q_deg, sampled: dict, u95_mm=None) -> list:
    """Per target, where it lies outside the calibrated region (the joint ranges a model was fitted on).

    Parameters
    ----------
    q_deg : ndarray, shape (n, N), deg
        The targets' joint angles, as the kinematics take them (the model's ``sampled`` ranges are in them).
    sampled : dict
        ``{"lower_deg": [N], "upper_deg": [N]}`` (:func:`pipeline.robot.model.predict.sampled_range`).
    u95_mm : ndarray, shape (n,), mm, optional
        Each target's stated u95 (contract section 14).

    Returns
    -------
    list, length n: None inside the region, else ``{"joint": the joint farthest beyond (1-based), "q_deg": its
    angle, "beyond_deg": how far beyond, "range_deg": [low, high] of that joint, "others": {joint: deg beyond} of
    the other joints beyond theirs, "u95_mm": float or None}`` and, when that joint's angle lies inside its range
    but in a stretch no sample pose reached (``sampled``'s ``gaps_deg``), ``"gap_deg": [low, high]`` of that
    stretch (``beyond_deg`` is then the distance to the nearer sampled angle).
    """
    q = np.atleast_2d(np.asarray(q_deg, float))
    lo, hi = np.asarray(sampled["lower_deg"], float), np.asarray(sampled["upper_deg"], float)
    b = beyond_deg(q, sampled)
    gaps = in_gap(q, sampled)
    out = []
    for k, row in enumerate(b):
        far = np.flatnonzero(row > 1e-9)      # the tolerance of pipeline.robot.model.predict.outside_range
        if not far.size:
            out.append(None)
            continue
        j = int(np.argmax(row))
        out.append({"joint": j + 1, "q_deg": float(q[k, j]), "beyond_deg": float(row[j]),
                    "range_deg": [float(lo[j]), float(hi[j])],
                    "others": {int(i) + 1: float(row[i]) for i in far if i != j},
                    "u95_mm": None if u95_mm is None else float(np.asarray(u95_mm, float)[k])})
        if gaps[k][j] is not None:
            out[-1]["gap_deg"] = gaps[k][j]
    return out


def outside_where(entry: dict, angle: bool = True) -> str:
    """One target of :func:`outside_region` in words: which joint (at which angle, ``angle``), how far beyond its
    calibrated range, the other joints beyond theirs, the stated u95."""
    also = "; ".join(f"joint {j} {d:.3g} deg beyond" for j, d in entry["others"].items())
    lo, hi = entry["range_deg"]
    if "gap_deg" in entry:
        a, b = entry["gap_deg"]
        where = (f"joint {entry['joint']} at {entry['q_deg']:.3f} deg, inside its range but in [{a:.2f}, {b:.2f}], "
                 f"a stretch no sample pose reached, {entry['beyond_deg']:.3g} deg from the nearer sampled angle"
                 if angle else f"{entry['beyond_deg']:.3g} deg into a stretch no sample pose reached")
    else:
        where = (f"joint {entry['joint']} at {entry['q_deg']:.3f} deg, {entry['beyond_deg']:.3g} deg beyond "
                 f"[{lo:.2f}, {hi:.2f}]" if angle else f"{entry['beyond_deg']:.3g} deg beyond")
    return (where
            + (f" (also {also})" if also else "")
            + (f"; u95_mm {entry['u95_mm']:.3f}" if entry["u95_mm"] is not None else "; no stated u95"))


def outside_summary(where: list) -> str:
    """One line on the targets :func:`outside_region` finds outside the calibrated region: how many, per joint (how
    many, the farthest beyond, the joint's calibrated range) and the range of their stated u95_mm; '' when none."""
    out = [w for w in where if w is not None]
    if not out:
        return ""
    joints: dict[int, list] = {}
    for w in out:
        for j, d in [(w["joint"], w["beyond_deg"]), *w["others"].items()]:
            joints.setdefault(j, []).append(d)
    u = [w["u95_mm"] for w in out if w["u95_mm"] is not None]
    return (f"{len(out)} of {len(where)} targets outside the calibrated region (the joint ranges the model was "
            "fitted on, and the stretches inside them no sample pose reached; the model extrapolates there): "
            + "; ".join(f"joint {j}: {len(d)}, up to {max(d):.3g} deg beyond" for j, d in sorted(joints.items()))
            + (f"; their u95_mm {min(u):.3f} to {max(u):.3f} mm (median {np.median(u):.3f})" if u else
               "; the model states no u95 (fitted before contract section 14)"))


@dataclass
class CorrectedTargets:
    """What :func:`correct_targets` returns for n rows of an N-joint robot.

    Attributes
    ----------
    targets : Targets
        The targets file as read (``point_id`` (n,), ``lines`` (n,) 1-based, ``payload_kg`` (n,) kg,
        ``payload_given`` (n,) bool, ...).
    result : Correction
        The corrected commands (``q_deg`` (n, N) deg, ``dq_arcsec`` (n, N) arcsec, ``status`` (n,), ...).
    csv : str
        The corrected program (:func:`pipeline.correct.write.corrected_csv`).
    payload_kg : float or None, kg
        The one payload the model was fitted at (rows without ``payload_kg`` are corrected at it, or at
        0 kg when None).
    assumed : str
        What the model assumes of the robot, in words (:func:`pipeline.robot.model.rigid.assumptions`).
    outside : list
        Per row, where it lies outside the calibrated region, or None (:func:`outside_region`).
    """

    targets: Targets
    result: Correction
    csv: str
    payload_kg: float | None
    assumed: str
    outside: list = field(default_factory=list)

    def report(self, out_path, seconds: float, max_correction_deg: float, closed=()) -> list[str]:
        """The console's lines: rows corrected and left as given (and the first of them, with its line),
        the largest correction (arcsec), residual (um) and u95 (mm), the rows outside the calibrated region (how
        many, then each with its line, joint, how far beyond and u95_mm; the first :data:`OUTSIDE_NAMED`), the
        orientation held, what was assumed.

        ``seconds`` the time the correction took; ``closed`` the joints (1-based) run closed loop.
        """
        res, tg, payload = self.result, self.targets, self.payload_kg
        c = res.counts()
        ok = res.status == "ok"
        worst = f", largest residual {res.residual_um[ok].max():.2g} um" if ok.any() else ""
        if res.u95_mm is not None and ok.any():
            worst += (f"; u95_mm {np.median(res.u95_mm[ok]):.3f} mm (median of the corrected rows, largest "
                      f"{res.u95_mm[ok].max():.3f} mm)")
        largest = f", largest correction {abs(res.dq_arcsec[ok]).max():.1f} arcsec" if ok.any() else ""
        lines = [f"{out_path}: {len(res.status)} rows in {seconds:.1f} s: {c['ok']} corrected{largest}"
                 f"{worst}; left as given: {c['outside_sampled_range']} outside the sampled joint range, "
                 f"{c['correction_too_large']} beyond --max-correction-deg {max_correction_deg:g}, "
                 f"{c['no_solution']} without a solution"]
        if (~ok).any():
            k = int(((~ok).nonzero())[0][0])
            lines.append(f"  first left as given: {tg.point_id[k]} (line {tg.lines[k]}): {res.reason[k]}")
        summary = outside_summary(self.outside)
        if summary:
            far = [k for k, w in enumerate(self.outside) if w is not None]
            lines.append(f"  {summary}; each, as given:")
            lines += [f"    line {tg.lines[k]}: {tg.point_id[k]}: {outside_where(self.outside[k])}"
                      for k in far[:OUTSIDE_NAMED]]
            if len(far) > OUTSIDE_NAMED:
                lines.append(f"    ... and {len(far) - OUTSIDE_NAMED} more (status outside_sampled_range in {out_path})")
        if ok.any():
            held_all = int((res.orientation_held[ok] == "all").sum())
            pos_only = int(sum(r.startswith("orientation not held") for r in res.reason[ok]))
            lines.append(f"  orientation held: all of it on {held_all} of {int(ok.sum())} corrected rows"
                         + (f"; {pos_only} corrected in position alone (holding the orientation too needed more "
                            f"than --max-correction-deg {max_correction_deg:g})" if pos_only else "")
                         + ("" if held_all + pos_only == ok.sum() else
                            "; the rest only about the axes the measurements determine"))
        missing = int((~tg.payload_given).sum())
        lines.append(f"  {self.assumed}"
                     + (f"; closed loop on their encoders: joints {' '.join(map(str, closed))}" if closed else "")
                     + (f"; {missing} row(s) without payload_kg corrected at {payload or 0.0:g} kg"
                        + ("" if payload is not None else " (the model was not fitted at one payload)")
                        if missing else ""))
        return lines


def correct_targets(targets_path, doc: dict, loaded: tuple, max_correction_deg: float) -> CorrectedTargets:
    """Correct every row of a targets file with a fitted robot model.

    Parameters
    ----------
    targets_path : path-like
        The targets file (:func:`pipeline.correct.targets.read_targets`): ``point_id, q1 … qN`` (deg),
        optional ``x_mm, y_mm, z_mm`` (mm, base frame), ``payload_kg``, ``dir1 … dirN``, ``temperature_c``.
    doc : dict
        The fit JSON (``payloads_kg``, ``joint_angles``, the stated uncertainty).
    loaded : tuple
        ``(robot, effects, model, sampled, frame)`` of
        :func:`pipeline.robot.model.predict.load_model_document` of ``doc``.
    max_correction_deg : float, deg
        A row needing a larger correction of any joint is left as given.

    Returns
    -------
    CorrectedTargets

    Raises
    ------
    InputError
        The first problem of the targets file (file, line, column).
    """
    robot, effects, model, sampled, frame = loaded
    payload = model_payload(doc.get("payloads_kg"))
    kin = ModelKinematics(robot, model)
    tg = read_targets(targets_path, len(robot.joints), nominal_xyz=lambda q: kin.nominal(robot.kinematic_angles(q))[1],
                      default_payload_kg=payload or 0.0)
    res = correct_recorded(kin, tg.q_deg, tg.target_mm, tg.dirs, tg.payload_kg, tg.temperature_c, sampled,
                           max_correction_deg, target_R=tg.target_R, stated=load_prediction(doc, model))
    text = corrected_csv(tg.point_id, res, res.dirs, tg.payload_kg, tg.temperature_c)
    # the model's ranges are in the angles the kinematics take (a coupled robot's, as correct_recorded compares)
    where = outside_region(robot.kinematic_angles(tg.q_deg), sampled, res.u95_mm)
    return CorrectedTargets(tg, res, text, payload, assumptions(doc, len(robot.joints)), where)
