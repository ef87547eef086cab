"""``jointcal export``: a fitted model in the forms a robot or its drives take (contract section 8).

The whole job between reading the inputs and writing the outputs, one function per case:

* :func:`export_encoder`: an encoder model as a compensation table;
* :func:`export_robot`: a fitted robot model as a URDF, UR's ``calibration.conf`` and kinematics YAML, or
  per-joint tables, each with what it cannot carry said in comments;
* :func:`heldout_export`: on another campaign's target poses, the held-out RMS of the full model and of
  what each format carries (:func:`heldout_line` in words).

The command (``pipeline.cli.deploy``) reads the files, writes the texts these return and prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..core.errors import InputError
from .chain import CHAIN_EFFECTS, TABLE_EFFECTS, export_chain, folded_chain, heldout_by_carrier, leftover_cost

#: The note of an encoder model's table (its comment line and the console's).
ENCODER_NOTE = "harmonic terms of the joint module's encoder model; correction = -error, added to the reading"
#: What each format holds, in words (the start of its note).
HOLDS = {"urdf": "a URDF holds a rigid chain (geometry, base, tool)",
         "ur": "UR's DH deltas and the ROS driver's YAML hold a rigid chain (geometry, base, tool)",
         "table": "joint tables hold what depends on each joint's own angle (joint_map, joint_harmonic, "
                  "backlash); with the chain `jointcal export --with-tables` writes"}


def ur_paths(out) -> tuple[Path, Path]:
    """``calibration.conf`` and kinematics YAML paths of ``--out``: a .yaml/.yml or .conf path and the other
    file beside it, or a folder for both."""
    out = Path(out)
    if out.suffix in (".yaml", ".yml"):
        return out.with_suffix(".conf"), out
    if out.suffix == ".conf":
        return out, out.with_suffix(".yaml")
    return out / "calibration.conf", out / "kinematics.yaml"


def export_encoder(doc, step_deg: float, model_path) -> tuple[str, int]:
    """An encoder model's compensation table as CSV text.

    Parameters
    ----------
    doc : dict
        The encoder model JSON (``jointcal fit``).
    step_deg : float, deg
        Angle step of the table, over 0-360 deg.
    model_path : path-like
        The model file, named by an error.

    Returns
    -------
    text : str
        The table (:func:`pipeline.export.table.table_csv`, :data:`ENCODER_NOTE` as its comment).
    n : int
        Its angles (rows).

    Raises
    ------
    InputError
        ``doc`` is no encoder model (line 1, column 1 of ``model_path``).
    ValueError
        A step the table cannot have (the command's --step-deg).
    """
    from ..encoder.evaluate import model_from_result
    from .table import encoder_table, table_csv

    try:
        model = model_from_result(doc)
        table = encoder_table(model, step_deg, joint=doc.get("module", 1) if isinstance(doc, dict) else 1)
    except (KeyError, TypeError) as exc:
        raise InputError(model_path, f"neither a fitted robot model nor an encoder model ({exc})", 1, 1) from None
    return table_csv(table, [ENCODER_NOTE]), len(table)


@dataclass
class RobotExport:
    """What :func:`export_robot` returns.

    Attributes
    ----------
    texts : list of (str, str)
        ``(kind, text)`` of each file to write, in order: ``("urdf", ...)``, ``("conf", ...), ("yaml", ...)``
        or ``("table", ...)``.
    note : str
        What the format holds and what leaving the rest out costs (mm RMS and max), in words.
    assumed : str
        What the model assumes of the robot (:func:`pipeline.robot.model.rigid.assumptions`).
    plain_model, tables_model : RobotErrorModel
        The rigid chains nearest the whole model, without and with the joint tables applied
        (:func:`pipeline.export.chain.export_chain`), for :func:`heldout_export`.
    """

    texts: list = field(default_factory=list)
    note: str = ""
    assumed: str = ""
    plain_model: object = None
    tables_model: object = None


def export_robot(model_path, doc: dict, loaded: tuple, fmt: str, step_deg: float = 1.0, with_tables: bool = False,
                 urdf=None) -> RobotExport:
    """A fitted robot model in one format, with what it cannot carry said in its comments.

    Parameters
    ----------
    model_path : path-like
        The model file (named in the comments).
    doc : dict
        The fit JSON (``parameters``, ``payloads_kg``, ``joint_angles``).
    loaded : tuple
        ``(robot, effects, model, sampled, frame)`` of :func:`pipeline.robot.model.predict.load_model_document`.
    fmt : {"urdf", "ur", "table"}
    step_deg : float, deg
        ``table``: angle step over each joint's sampled range.
    with_tables : bool
        ``urdf``, ``ur``: the chain for drives that also apply the joint tables.
    urdf : (path-like, str, str or None, array_like or None), optional
        ``urdf``: ``(path, tip, base_link, tool_mm)`` of the URDF file the robot was imported from, to
        rewrite (only its revolute joints' ``<origin>`` elements change, by the calibration's amounts; the
        SMR is added as a fixed child of ``tip``, the link the SMR is given in; ``base_link`` the link whose
        frame is the model's base frame, None: the URDF's root; ``tool_mm`` (3,) mm the SMR in ``tip``'s
        frame as given to ``jointcal import``, None: ``tip``'s origin); None: a URDF of the chain alone.

    Returns
    -------
    RobotExport

    Raises
    ------
    InputError
        The URDF file to rewrite is not readable or does not fit the robot (its path, no line).
    """
    from ..robot.model.rigid import assumptions

    robot, effects, model, sampled, frame = loaded
    plain_model, plain_how = export_chain(robot, model, doc, sampled)
    tables_model, tables_how = export_chain(robot, model, doc, sampled, with_tables=True)
    chain_model, chain_how = (tables_model, tables_how) if with_tables else (plain_model, plain_how)
    tabled = with_tables or fmt == "table"
    carried = CHAIN_EFFECTS + TABLE_EFFECTS if tabled else CHAIN_EFFECTS
    cost = leftover_cost(robot, model, sampled, carried, chain=tables_model if tabled else chain_model,
                         payloads=doc.get("payloads_kg"))
    what = HOLDS[fmt]
    if with_tables:
        what += " for drives that apply the joint tables (--format table)"
    if cost["left_out"]:
        what += f"; the chain written is {chain_how}" if fmt != "table" else ""
        note = (f"{what}; it cannot carry the rest of {', '.join(cost['left_out'])}: the model's prediction moves by "
                f"{cost['rms_mm']:.4f} mm RMS, {cost['max_mm']:.4f} mm max without it ({cost['n']} poses: "
                f"{cost['conditions']})")
    else:
        note = f"{what}; the model has nothing else: it is carried whole"
    assumed = assumptions(doc, len(robot.joints))
    comments = [f"jointcal export, format {fmt}, of {model_path}", note, assumed]
    if fmt == "urdf":
        texts = [("urdf", _urdf_text(robot, chain_model, comments, urdf))]
    elif fmt == "ur":
        texts = _ur_texts(robot, effects, doc, folded_chain(robot, chain_model), comments)
    else:
        from .table import robot_table, table_csv

        table = robot_table(robot, model, sampled, step_deg)
        comments += table.attrs.get("notes", [])
        if table.empty:
            comments.append("the model has no effect of a joint's own angle: the table is empty")
        texts = [("table", table_csv(table, comments))]
    return RobotExport(texts, note, assumed, plain_model, tables_model)


def _urdf_text(robot, chain_model, comments: list[str], urdf) -> str:
    """The URDF: the given one with the calibration folded into its revolute joints' origins
    (:func:`pipeline.export.urdf.rewrite_urdf_file`), or the chain alone."""
    from .urdf import chain_urdf, rewrite_urdf_file

    chain = folded_chain(robot, chain_model)
    if urdf is None:
        return chain_urdf(robot.name + "_calibrated", chain, comments)
    path, tip, base_link, tool_mm = urdf
    return rewrite_urdf_file(path, tip, chain, comments, base_link,
                             nominal=folded_chain(robot, chain_model, keep=()), tool_mm=tool_mm,
                             joint1_reversed=bool(robot.coupling_matrix[0, 0] < 0))


def _ur_texts(robot, effects, doc: dict, chain: dict, comments: list[str]) -> list[tuple[str, str]]:
    """``calibration.conf`` deltas against UR's published DH (a robot imported from one) or the nominal
    robot's, and the ROS driver's kinematics YAML."""
    from ..robot.model.estimator import RobotErrorModel
    from .ur import calibration_conf, kinematics_yaml, published_reference, standard_dh

    nominal = published_reference(robot, effects, doc["parameters"], folded_chain)   # a UR's own calibration
    if nominal is None:
        nominal_model = RobotErrorModel.from_parameters(robot, effects,
                                                        [dict(p, value=0.0) for p in doc["parameters"]])
        nominal = standard_dh(folded_chain(robot, nominal_model))
    else:
        comments.append(f"deltas against UR's published DH of the {robot.ur_model.upper()} (the robot was "
                        "imported from its calibration.conf): this is its new calibration.conf")
    fitted = standard_dh(chain, reference=nominal)
    return [("conf", calibration_conf(fitted, nominal, chain["smr"], comments)),
            ("yaml", kinematics_yaml(chain, comments))]


def heldout_export(model_path, loaded: tuple, exported: RobotExport, campaign) -> tuple[dict, str]:
    """Held-out RMS (mm) on a campaign's target poses of the full model, of what a URDF / UR's parameters
    carry, and of that with the joint tables (:func:`pipeline.export.chain.heldout_by_carrier`).

    Wild measurements are named and left out, as fit and predict do (contract section 12); the
    errors with them are given beside (``with_outliers``).

    Parameters
    ----------
    model_path : path-like
    loaded : tuple
        ``(robot, effects, model, sampled, frame)`` of the fitted model.
    exported : RobotExport
        :func:`export_robot`'s (its two chains).
    campaign : path-like
        A campaign folder of the same robot with target poses.

    Returns
    -------
    numbers : dict
        The JSON document (``n``, ``full_rms_mm``, ``chain_rms_mm``, ..., mm; the wild points; ``model``,
        ``campaign``, ``effects``).
    wild : str
        The wild measurements in words ('' when none).

    Raises
    ------
    InputError
        Another robot's campaign, or one without target poses.
    """
    from ..robot.campaign.ingest import robot_data_sets
    from ..robot.model.outliers import describe, find_wild
    from ..robot.model.predict import same_robot_problem

    robot, effects, model, sampled, frame = loaded
    other, (sample, target) = robot_data_sets(campaign, ("sample",), ("target",))
    problem = same_robot_problem(robot, other)
    if problem:
        raise InputError(Path(campaign) / "robot.toml", problem, 1, 1)
    if target.n == 0:
        raise InputError(Path(campaign) / "poses.csv", "no target poses to measure the held-out error on", 1, "set")
    wild = find_wild(robot, effects, sample, target, campaign)
    h = heldout_by_carrier(robot, model, wild.clean(sample, target)[1], exported.plain_model, exported.tables_model)
    if wild.target.any():
        h["with_outliers"] = {k: v for k, v in heldout_by_carrier(robot, model, target, exported.plain_model,
                                                                  exported.tables_model).items()
                              if k.endswith("_mm") or k == "n"}
    h.update(wild.document())
    h.update({"model": str(model_path), "campaign": str(campaign), "effects": [e.name for e in effects]})
    return h, describe(wild)


def heldout_line(h: dict, campaign) -> str:
    """The console's line of :func:`heldout_export`'s numbers (mm) on ``campaign``'s target poses."""
    return (f"held-out RMS on {h['n']} target poses of {campaign}: full model {h['full_rms_mm']:.3f} mm; "
            f"what a URDF / UR's parameters carry {h['chain_rms_mm']:.3f} mm (the model's own geometry "
            f"alone {h['model_geometry_rms_mm']:.3f} mm; leaves out "
            f"{', '.join(h['chain_left_out']) or 'nothing'}); with the joint tables {h['chain_tables_rms_mm']:.3f} mm "
            f"(the model's own geometry with them {h['model_geometry_tables_rms_mm']:.3f} mm) "
            f"(leaves out {', '.join(h['chain_tables_left_out']) or 'nothing'}); nominal {h['nominal_rms_mm']:.3f} mm")
