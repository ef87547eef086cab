"""``jointcal correct --targets``: a targets file corrected with a fitted robot model (contract section 8).

:func:`correct_targets` is the whole job between reading the inputs and writing the output: the
targets read and checked (:func:`pipeline.correct.targets.read_targets`), every row corrected
(:func:`pipeline.correct.robot.correct_commands`), the corrected program as CSV text
(:func:`pipeline.correct.write.corrected_csv`). The command (``pipeline.cli.deploy``) reads the model,
writes the text and prints.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..robot.model.rigid import assumptions, model_payload
from ..robot.model.uncertainty import load_prediction
from .robot import Correction, ModelKinematics, correct_commands
from .targets import Targets, read_targets
from .write import corrected_csv


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
    """

    targets: Targets
    result: Correction
    csv: str
    payload_kg: float | None
    assumed: str


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
    tg = read_targets(targets_path, len(robot.joints), nominal_xyz=lambda q: kin.nominal(q)[1],
                      default_payload_kg=payload or 0.0)
    res = correct_commands(kin, tg.q_deg, tg.target_mm, tg.dirs, tg.payload_kg, tg.temperature_c, sampled,
                           max_correction_deg, target_R=tg.target_R, stated=load_prediction(doc, model))
    text = corrected_csv(tg.point_id, res, res.dirs, tg.payload_kg, tg.temperature_c)
    return CorrectedTargets(tg, res, text, payload, assumptions(doc, len(robot.joints)))
