"""Putting a fitted model on the robot (contract sections 8 and 10): ``jointcal correct`` (robot
programs and encoder readings), ``jointcal export`` and ``jointcal simulate measure``. Thin commands.
"""

from __future__ import annotations

from pathlib import Path

import click

from ..core.errors import InputError
from . import encoder
from .common import read_json


def _need_file(path, what: str) -> None:
    if not Path(path).is_file():
        raise InputError(path, f"no such file ({what})", None, None)


def _need_program(path) -> None:
    if not Path(path).exists():
        raise InputError(path, "no such file or folder (the robot program)", None, None)


def _is_robot_model(doc) -> bool:
    return isinstance(doc, dict) and "robot_toml" in doc and doc.get("kind", "robot") == "robot"


def _load_robot_model(path, doc):
    from ..robot.model.predict import load_model_document

    return load_model_document(doc, path)


def _joint_list(text, n_joints: int, option: str) -> list[int]:
    """Joint numbers given as ``"1 2 3"`` or ``"1,2,3"`` (1-based, each within the robot's joints)."""
    out = []
    for part in " ".join(text or ()).replace(",", " ").split():
        if not part.isdigit() or not 1 <= int(part) <= n_joints:
            raise click.BadParameter(f"'{part}' is not a joint number 1..{n_joints}", param_hint=option)
        out.append(int(part))
    return sorted(set(out))


def _angle_problem(model_path, doc, closed_loop, n_joints: int) -> list[int]:
    """The joints run closed loop on their encoders (--closed-loop-joints); refuses a model whose angle
    source does not match how the program runs the joints (:func:`pipeline.correct.robot.angle_mismatch`)."""
    from ..correct.robot import angle_mismatch

    closed = _joint_list(closed_loop, n_joints, "--closed-loop-joints")
    problem = angle_mismatch(doc.get("joint_angles"), closed)
    if problem:
        raise InputError(model_path, problem, _json_line(model_path, "joint_angles"), "joint_angles")
    return closed


def _json_line(path, key: str):
    """1-based line of ``"key":`` in a JSON file (None when absent)."""
    try:
        for k, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), 1):
            if f'"{key}"' in line:
                return k
    except OSError:
        pass
    return None


@click.command("correct")
@click.option("--model", "model_path", required=True, type=click.Path(),
              help="A fitted model: a robot fit JSON (jointcal fit --campaign) or an encoder model (jointcal fit).")
@click.option("--targets", "targets_path", type=click.Path(dir_okay=False),
              help="Robot model: the program's points, one row per point in visiting order: point_id, q1 … qN (deg), "
                   "optional x_mm, y_mm, z_mm (point to reach, base frame; default the nominal kinematics of q), "
                   "payload_kg, dir1 … dirN (default from the visiting order), temperature_c (default 20).")
@click.option("--out", "out_path", type=click.Path(),
              help="Robot model: the corrected program (CSV: point_id, q1 … qN deg, dq1_arcsec … dqN_arcsec, x_mm, "
                   "y_mm, z_mm of the corrected commands' nominal kinematics, model_residual_um, orientation_held, status, "
                   "reason); with --program: the folder the filtered program goes to, under its own file names.")
@click.option("--program", "program_path", type=click.Path(),
              help="Robot model: a robot program to filter (contract section 11): a file, told by extension: .src "
                   "(KUKA KRL, with the .dat of the same name and a $config.dat beside it), .mod/.prg/.sys/.modx (ABB "
                   "RAPID), .ls (FANUC TP ASCII), .script/.urscript (URScript); or a folder of one program (RAPID "
                   "modules read together, KRL with the folder's $config.dat). See docs/programs.md.")
@click.option("--tool", "tool_text", default=None,
              help="--program: the TCP in the vendor's flange frame (FANUC faceplate, KUKA $FLANGE, ABB tool0, UR tool "
                   "flange: docs/your-robot.md) where the program does not define it (KRL TOOL_DATA[n] without "
                   "$config.dat, "
                   "FANUC UTOOL, an undeclared RAPID tool, URScript without set_tcp): \"X Y Z A B C\", mm and the "
                   "format's rotation (KRL A B C, FANUC W P R deg; RAPID \"x y z q1 q2 q3 q4\"; UR rotation vector rad).")
@click.option("--base", "base_text", default=None,
              help="--program: the program's base in the robot's base frame where the program does not define it "
                   "(KRL BASE_DATA[n], FANUC UFRAME[n], an undeclared RAPID work object); same form as --tool. KRL "
                   "base 0, FANUC UF : 0 and RAPID wobj0 are the robot's base frame.")
@click.option("--payload", "payload_kg", default=None, type=click.FloatRange(min=0),
              help="--program: the mass (kg) the robot carries where the program does not state it (RAPID tooldata "
                   "load and GripLoad, URScript set_payload, KRL $LOAD / LOAD_DATA[n] of $config.dat are read). "
                   "Default: the model's payload when it was fitted at one; a model with compliance fitted at several "
                   "refuses a motion whose payload nobody knows.")
@click.option("--json", "json_path", default=None, type=click.Path(dir_okay=False),
              help="--program: write the per-target report as JSON.")
@click.option("--max-correction-deg", default=0.5, show_default=True, type=click.FloatRange(min=0, min_open=True),
              help="Robot model: a row needing a larger correction of any joint is left as given (status "
                   "correction_too_large).")
@click.option("--closed-loop-joints", "closed_loop", multiple=True, metavar="J...",
              help="Robot model: joints that follow their secondary encoders (e.g. gratings) in a closed loop on the "
                   "robot, as \"1 2 3\" or 1,2,3. A model fitted on those encoders' angles is refused for a "
                   "program that runs them open loop; a model fitted on commanded angles for joints run closed loop.")
@click.option("--input", "input_path", default="-", show_default=True, type=click.Path(),
              help="Encoder model: CSV with a column of joint readings, or - for standard input.")
@click.option("--column", default="encoder_deg", show_default=True, help="Encoder model: column of readings (deg).")
@click.option("--output", "output_path", default="-", show_default=True, type=click.Path(),
              help="Encoder model: where to write the CSV with corrected_deg and correction_arcsec added.")
@click.pass_context
def correct(ctx, model_path, targets_path, out_path, program_path, tool_text, base_text, payload_kg, json_path,
            max_correction_deg, closed_loop, input_path, column, output_path):
    """Correct with a fitted model: a robot program's commands, or an encoder's readings.

    \b
    Robot model (contract section 8): every effect of the model is used - geometry, base, tool,
    joint maps and harmonics, compliance with the row's payload, backlash with the row's
    approach direction, thermal with the row's temperature. Each row's commands are moved, by
    Newton iterations on the model's own Jacobian, until the model puts the SMR on the point
    (model_residual_um <= 1); the flange keeps the program's orientation in the directions the
    measurements determine (orientation_held: all, none, "all but about (ux uy uz)" or "about
    (hx hy hz) only", base frame; with one SMR and a fitted tool offset, none); the correction is
    the smallest that does both (a redundant arm's self-motion is not used). Rows outside the joint ranges
    the model was fitted on, beyond --max-correction-deg, or without a solution are left as
    given, and the status and reason columns say why.
    \b
    What the model was made for travels with it (the fit JSON's joint_angles and payloads_kg): a
    row without payload_kg is corrected at the payload the model was fitted at (when it was one,
    else 0 kg); a model fitted on secondary encoders' angles (the KR210 cell's gratings on joints
    1-3) is refused for joints run open loop unless --closed-loop-joints names them. The console
    says what was assumed.
      jointcal correct --model results/real/C_diagnosed.json --targets program.csv --out corrected.csv
    \b
    Encoder model: corrected = reading - error(reading) (see --input, --column, --output).
      printf 'encoder_deg\\n10.0\\n95.5\\n' | jointcal correct --model results/encoder/a_model.json
    \b
    Robot program (--program, contract section 11): each Cartesian target goes through the
    nominal controller's inverse kinematics on the branch its configuration data name (KUKA S/T,
    ABB cf1 cf4 cf6 cfx, FANUC CONFIG + turns of joints 1, 4, 6; a linear move and every UR move:
    the branch of the point before, nearest its joints; the robot starts at the middle of its
    joint ranges), is corrected as above, and is written back as the nominal forward kinematics
    of the corrected joints in its own tool and base frame; a joint target is corrected. Only
    the numbers of motion targets change, each with its decimals; every other byte stays. Joint
    values in a program are the robot.toml's joint angles (FANUC: no J2/J3 interaction). Left
    as given and named: targets computed or streamed at run time, declared nowhere, without a
    solution on their branch, refused by the model, or whose branch or turn would change; a
    statement the filter does not need passes through. The payload is the program's own where it
    states one (tooldata, GripLoad, set_payload, $LOAD / LOAD_DATA), else --payload.
    Conventions: docs/programs.md; every format and key: docs/formats.md.
      jointcal correct --model fit.json --program weld.src --out filtered/ --json report.json
    """
    doc = read_json(model_path)
    if program_path and _is_robot_model(doc):
        if not out_path:
            raise click.UsageError("--program needs --out DIR (the folder for the filtered program)")
        return _correct_program(model_path, doc, program_path, out_path, tool_text, base_text, payload_kg, json_path,
                                max_correction_deg, closed_loop)
    if not _is_robot_model(doc):
        if targets_path or out_path:
            raise InputError(model_path, "--targets/--out correct a robot program, and this is not a fitted robot "
                             "model (for an encoder model use --input, --column and --output)", 1, 1)
        return ctx.invoke(encoder.correct, model_path=model_path, input_path=input_path, column=column,
                          output_path=output_path)
    if not targets_path or not out_path:
        raise click.UsageError("a robot model needs --targets FILE and --out FILE.csv")
    import time

    from ..core.files import write_text
    from ..correct.run import correct_targets

    _need_file(targets_path, "the targets: point_id, q1 … qN, one row per point")
    loaded = _load_robot_model(model_path, doc)
    closed = _angle_problem(model_path, doc, closed_loop, len(loaded[0].joints))
    t0 = time.perf_counter()
    run = correct_targets(targets_path, doc, loaded, max_correction_deg)
    write_text(out_path, run.csv)
    for line in run.report(out_path, time.perf_counter() - t0, max_correction_deg, closed):
        click.echo(line, err=True)


def _frame_option(text, name, fmt):
    if text is None:
        return None
    from ..programs.formats import frame_arity

    try:
        values = [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        raise click.BadParameter(f"'{text}': numbers separated by spaces", param_hint=name) from None
    if len(values) != frame_arity(fmt):
        raise click.BadParameter(f"'{text}': {frame_arity(fmt)} numbers for this program's format", param_hint=name)
    return values


def _correct_program(model_path, doc, program_path, out_dir, tool_text, base_text, payload_kg, json_path,
                     max_correction_deg, closed_loop=()):
    import time

    from ..core.files import write_json
    from ..programs.io import read_program, write_all
    from ..programs.run import filter_with_model

    _need_program(program_path)
    loaded = _load_robot_model(model_path, doc)
    closed = _angle_problem(model_path, doc, closed_loop, len(loaded[0].joints))
    t0 = time.perf_counter()
    program = read_program(program_path)
    tool = _frame_option(tool_text, "--tool", program.format)
    base = _frame_option(base_text, "--base", program.format)
    run = filter_with_model(program, doc, loaded, tool, base, payload_kg, max_correction_deg)
    written = write_all(out_dir, program, run.texts)
    for line in run.report(written, time.perf_counter() - t0, program.notes, payload_kg, closed):
        click.echo(line, err=True)
    if json_path:
        write_json(json_path, {"program": str(program_path), "format": program.format, "model": str(model_path),
                               "payload_kg": payload_kg, "counts": run.counts, "files": [str(w) for w in written],
                               "targets": run.filtered.rows})


# ------------------------------------------------------------------------------ simulate measure
@click.command("measure")
@click.option("--truth", "truth_path", default="raw/truth/robot/kr210.json", show_default=True,
              type=click.Path(dir_okay=False), help="Truth of the virtual cell, as `jointcal simulate robot` wrote it.")
@click.option("--poses", "poses_path", default=None, type=click.Path(dir_okay=False),
              help="Commanded poses in visiting order: point_id, q1 … qN (deg), optional payload_kg, dir1 … dirN "
                   "(default from the visiting order), temperature_c (default 20), set (default target).")
@click.option("--campaign", required=True, type=click.Path(file_okay=False),
              help="Campaign folder to write (robot.toml, poses.csv, tracker.csv; contract section 2).")
@click.option("--robot", "robot_path", default=None, type=click.Path(dir_okay=False),
              help="The cell's nominal robot.toml (default: the truth's, the campaign folder's, or raw/robot/<name>).")
@click.option("--seed", type=int, default=None, help="Seed of the jitter and tracker noise (default: the cell's).")
@click.option("--closed-loop-joints", "closed_loop", multiple=True, metavar="J...",
              help="Joints that run closed loop on their gratings (the second paper's loop, Eq. 26, until the "
                   "grating reads the command), as \"1 2 3\" or 1,2,3; the campaign then has the grating readings. "
                   "Default: every joint open loop. The paper's cell has gratings on joints 1-3, a user's cell none.")
@click.option("--program", "program_path", default=None, type=click.Path(),
              help="Instead of --poses: a robot program (.src, .mod, .ls, .script) played by the nominal controller "
                   "(as jointcal correct --program reads it); point_id = the target's name (#2, #3 for a target "
                   "visited again).")
@click.option("--tool", "tool_text", default=None, help="--program: as for jointcal correct --program.")
@click.option("--base", "base_text", default=None, help="--program: as for jointcal correct --program.")
@click.option("--payload", "payload_kg", default=None, type=click.FloatRange(min=0),
              help="--program: the mass (kg) the robot carries where the program states none (default 0).")
def measure_cmd(truth_path, poses_path, campaign, robot_path, seed, closed_loop, program_path, tool_text, base_text,
                payload_kg):
    """Measure commanded poses on the virtual cell (contract section 10; lengths mm, angles deg).

    The cell whose truth `jointcal simulate robot` wrote moves to each pose in the file's order -
    true geometry and tool, transmission error, compliance under the row's payload, backlash by the
    row's approach direction, jitter, any hidden effect - and its tracker (same noise) measures the
    SMR in the robot base frame. Writes a campaign folder: every pose `target` unless `set` says.
    Open loop by default; --closed-loop-joints runs those joints on their gratings (the cell's
    transmission error, compliance and backlash of those joints are then taken out by the loop).
    A simulator: it reads the truth, which the pipeline never does.

    \b
      jointcal simulate measure --poses corrected.csv --campaign /tmp/check
    """
    from ..robot.cell.measure import measure_cell, read_commanded_poses

    if bool(poses_path) == bool(program_path):
        raise click.UsageError("give --poses FILE or --program FILE (one of them)")
    if program_path:
        return _measure_program(truth_path, program_path, campaign, robot_path, seed, tool_text, base_text, payload_kg,
                                closed_loop)
    _need_file(poses_path, "the commanded poses: point_id, q1 … qN")
    robot, cell = measure_cell(truth_path, campaign, robot_path)
    p = read_commanded_poses(poses_path, robot)
    q, sets = p["q_deg"], p["set"]
    closed = _write_measured(campaign, robot, cell, p["point_id"], sets, q, p["dirs"], p["payload_kg"],
                             p["temperature_c"], seed, closed_loop)
    loop = (f"joints {' '.join(map(str, closed))} closed loop on their gratings, the others open loop" if closed
            else "every joint open loop")
    click.echo(f"{campaign}: measured {len(q)} poses on the cell of {truth_path} "
               f"({int((sets == 'sample').sum())} sample, {int((sets == 'target').sum())} target; {loop})", err=True)


def _write_measured(campaign, robot, cell, point_id, sets, q, dirs, payload, temp, seed, closed_loop) -> list[int]:
    """Move the cell to the poses q (n, N) deg, measure them, and write the campaign folder; returns the
    joints run closed loop on their gratings."""
    from ..core.files import write_text
    from ..robot.cell.measure import measured_campaign

    closed = _joint_list(closed_loop, len(robot.joints), "--closed-loop-joints")
    try:
        files = measured_campaign(robot, cell, point_id, sets, q, dirs, payload, temp, seed, closed)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--closed-loop-joints") from None
    for name, text in files.items():
        write_text(Path(campaign) / name, text)
    return closed


def _measure_program(truth_path, program_path, campaign, robot_path, seed, tool_text, base_text, payload_kg,
                     closed_loop=()):
    import numpy as np

    from ..programs.io import read_program
    from ..programs.run import played_poses
    from ..robot.cell.measure import measure_cell

    _need_program(program_path)
    robot, cell = measure_cell(truth_path, campaign, robot_path)
    program = read_program(program_path)
    p = played_poses(program, robot, _frame_option(tool_text, "--tool", program.format),
                     _frame_option(base_text, "--base", program.format), payload_kg)
    for t, r in p.not_played:
        click.echo(f"  {t.file}:{t.line}: {t.name} not played: {r}", err=True)
    if not len(p.q_deg):
        raise InputError(program_path, "no motion of the program could be played", None, None)
    n = len(p.q_deg)
    _write_measured(campaign, robot, cell, p.point_id, np.full(n, "target"), p.q_deg, None, p.payload_kg,
                    np.full(n, 20.0), seed, closed_loop)
    click.echo(f"{campaign}: measured {n} motions of {program_path} on the cell of {truth_path} "
               f"({len(p.not_played)} not played)", err=True)


# ------------------------------------------------------------------------------ export
@click.command("export")
@click.option("--model", "model_path", required=True, type=click.Path(),
              help="A fitted robot model (jointcal fit --campaign); for --format table also an encoder model.")
@click.option("--format", "fmt", required=True, type=click.Choice(["urdf", "ur", "table"]),
              help="urdf: the robot with geometry, base and tool in the joint origins; ur: calibration.conf "
                   "[mounting] deltas (standard DH, rad and m) and the ROS driver's kinematics YAML; table: one "
                   "compensation table per joint (CSV).")
@click.option("--out", required=True, type=click.Path(),
              help="File to write (ur: a .yaml or .conf path, the other file beside it, or a folder for both).")
@click.option("--urdf", "urdf_path", default=None, type=click.Path(dir_okay=False),
              help="urdf: rewrite this URDF of the robot (the one it was imported from) instead: only its revolute "
                   "joints' <origin> elements change, by the calibration's amounts; every link keeps its frame, "
                   "tool0, the flange and every fixed child stay; the SMR is added as a fixed child 'smr' of --tip.")
@click.option("--tip", default=None, help="urdf with --urdf: the link the SMR is given in (as for jointcal import).")
@click.option("--tool-mm", "tool_mm", nargs=3, type=float, default=None, metavar="X Y Z",
              help="urdf with --urdf: the SMR in the --tip link's frame, mm (as for jointcal import; default its origin).")
@click.option("--base", "base_link", default=None,
              help="urdf with --urdf: the link whose frame is the model's base frame (as for jointcal import; "
                   "default the URDF's root).")
@click.option("--heldout", "heldout_campaign", default=None, type=click.Path(file_okay=False),
              help="A campaign of the same robot (e.g. the fit's own): measure on its target poses the held-out RMS "
                   "of the full model, of what a URDF / UR's parameters carry, and of that plus the joint tables.")
@click.option("--json", "json_out", default=None, type=click.Path(dir_okay=False),
              help="With --heldout: write those numbers (mm) and what each leaves out as JSON.")
@click.option("--step-deg", default=1.0, show_default=True, type=click.FloatRange(min=0.001),
              help="table: angle step of the tables (deg), over each joint's sampled range (encoder: 0-360).")
@click.option("--with-tables", is_flag=True,
              help="urdf, ur: write the chain for a robot whose drives also apply the model's joint tables "
                   "(--format table): fitted with the tables applied. Default: the chain alone, nearest the whole model.")
def export_cmd(model_path, fmt, out, urdf_path, tip, tool_mm, base_link, heldout_campaign, json_out, step_deg,
               with_tables):
    """Write a fitted model in a form a robot or its drives take (contract section 8).

    \b
    Each format says here, and in the file as comments, which fitted effects it cannot carry and
    what leaving them out costs: how far the model's prediction moves without them (RMS and max,
    mm, over the joint ranges the model was fitted on), and what the model assumes (which angle
    each joint takes, the payload it was fitted at). A URDF and UR's parameters carry a rigid
    chain: the one nearest the whole model (fitted by jointcal fit to the model's own predictions
    at the poses it was fitted on; for geometry + base + tool alone, that geometry exactly); with
    --with-tables the one for drives that also apply the joint tables. The joint tables carry
    joint maps, joint harmonics and backlash; none carries compliance, thermal expansion or
    Chebyshev error transfer.
      jointcal export --model results/real/C_diagnosed.json --format urdf --out ur10_calibrated.urdf
    """
    from ..core.files import write_text
    from ..export.run import ENCODER_NOTE, export_encoder, export_robot, heldout_export, heldout_line, ur_paths

    doc = read_json(model_path)
    if not _is_robot_model(doc):
        if fmt != "table":
            raise InputError(model_path, f"--format {fmt} needs a fitted robot model (jointcal fit --campaign); "
                             "an encoder model exports as --format table", 1, 1)
        try:
            text, n = export_encoder(doc, step_deg, model_path)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--step-deg") from None
        write_text(out, text)
        click.echo(f"{out}: {n} angles; {ENCODER_NOTE}", err=True)
        return
    loaded = _load_robot_model(model_path, doc)
    urdf = None
    if fmt == "urdf" and urdf_path:
        if not tip:
            raise click.UsageError("--urdf needs --tip LINK (the link the SMR is given in, as for jointcal import)")
        _need_file(urdf_path, "the robot's URDF")
        urdf = (urdf_path, tip, base_link, tool_mm)
    exported = export_robot(model_path, doc, loaded, fmt, step_deg, with_tables, urdf)
    paths = {"urdf": [out], "table": [out], "ur": list(ur_paths(out))}[fmt]
    for path, (_, text) in zip(paths, exported.texts):
        write_text(path, text)
    click.echo(f"{', '.join(map(str, paths))}: written; {exported.note}", err=True)
    click.echo(f"  {exported.assumed}", err=True)
    if heldout_campaign:
        from ..core.files import write_json

        h, wild = heldout_export(model_path, loaded, exported, heldout_campaign)
        if wild:
            click.echo(f"jointcal: {heldout_campaign}: {wild}", err=True)
        click.echo(heldout_line(h, heldout_campaign), err=True)
        if json_out:
            write_json(json_out, h)
