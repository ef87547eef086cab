"""``jointcal export --format urdf``: the fitted rigid chain as a URDF (contract section 8).

Geometry, base and tool are folded into the joint origins (:func:`pipeline.export.chain.folded_chain`):
joint i's origin is the placement of its axis (z) in the frame of joint i-1, its fitted zero offset a
rotation about the axis in the origin; the flange and the SMR are fixed frames after the last joint.
Numbers are written at full precision (``repr``): 6 significant digits cost several um at the tool.
rpy is URDF's roll-pitch-yaw, ``R = Rz(yaw) Ry(pitch) Rx(roll)``. ``<calibration rising>`` is not used
(pinocchio and most parsers ignore it).

With the user's own URDF (``--urdf``, ``--tip`` and ``--tool-mm`` as given to ``jointcal import``) only
the ``<origin>`` elements of the revolute joints on the root-to-tip chain change, each by the calibration's
amounts, and the SMR is added as a fixed child of the tip link (:func:`rewrite_urdf`): every link keeps its
frame on its body, every fixed child (``tool0``, the flange, meshes, a camera) stays where the file puts it.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin


def _num(v) -> str:
    v = float(v)
    return "0" if v == 0.0 else repr(v)


def origin_attrs(M) -> tuple[str, str]:
    """``xyz`` and ``rpy`` attribute values of an SE3 (m, rad), full precision."""
    rpy = pin.rpy.matrixToRpy(M.rotation)
    return " ".join(_num(v) for v in M.translation), " ".join(_num(v) for v in rpy)


def chain_urdf(name: str, chain: dict, comments: list[str]) -> str:
    """URDF text of a folded chain: links ``base_link``, ``link1..linkN``, ``flange``, ``smr``;
    revolute joints ``joint1..jointN`` about z with the robot's limits; fixed joints to the flange
    and the SMR. ``comments``: lines written at the top (what the file cannot carry)."""
    out = ['<?xml version="1.0"?>']
    out += [f"<!-- {c.replace('--', '-')} -->" for c in comments]
    out.append(f'<robot name="{name}">')
    out.append('  <link name="base_link"/>')
    parent = "base_link"
    for i, o in enumerate(chain["origins"]):
        xyz, rpy = origin_attrs(o)
        out += [f'  <link name="link{i + 1}"/>',
                f'  <joint name="joint{i + 1}" type="revolute">',
                f'    <parent link="{parent}"/>', f'    <child link="link{i + 1}"/>',
                f'    <origin xyz="{xyz}" rpy="{rpy}"/>', '    <axis xyz="0 0 1"/>',
                f'    <limit lower="{_num(chain["lower_rad"][i])}" upper="{_num(chain["upper_rad"][i])}" '
                'effort="1000" velocity="3.14"/>',
                '  </joint>']
        parent = f"link{i + 1}"
    for child, M in (("flange", chain["flange"]), ("smr", chain["smr"])):
        xyz, rpy = origin_attrs(M)
        out += [f'  <link name="{child}"/>', f'  <joint name="{parent}_to_{child}" type="fixed">',
                f'    <parent link="{parent}"/>', f'    <child link="{child}"/>',
                f'    <origin xyz="{xyz}" rpy="{rpy}"/>', '  </joint>']
        parent = child
    out.append("</robot>")
    return "\n".join(out) + "\n"


def urdf_positions(text: str, tip: str, q_deg) -> np.ndarray:
    """pinocchio's forward kinematics of a URDF text: position (n, 3) mm of link ``tip``."""
    model = pin.buildModelFromXML(text)
    data = model.createData()
    fid = model.getFrameId(tip)
    out = []
    for q in np.deg2rad(np.atleast_2d(q_deg)):
        pin.forwardKinematics(model, data, q)
        out.append(pin.updateFramePlacement(model, data, fid).translation.copy() * 1000.0)
    return np.array(out)


def _chain_joints(root: ET.Element, tip: str) -> list[ET.Element]:
    """The joints from the URDF's root link to ``tip``, root first (ValueError when ``tip`` is unknown)."""
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    links = {l.get("name") for l in root.findall("link")}
    if tip not in links:
        raise UrdfProblem(f"no link '{tip}' in the URDF (links: {', '.join(sorted(links)[:8])} …)")
    chain, link = [], tip
    while link in by_child:
        j = by_child[link]
        chain.append(j)
        link = j.find("parent").get("link")
    return chain[::-1]


class UrdfProblem(ValueError):
    """A URDF that cannot take the model, with the element it is about (``tag``, ``name``) to locate it."""

    def __init__(self, message: str, tag: str = "robot", name: str | None = None):
        super().__init__(message)
        self.tag, self.name = tag, name


#: how far (mm, deg) a URDF joint axis may lie from where the model's nominal robot has it
AXIS_TOL_MM = 1e-3
AXIS_TOL_DEG = 1e-4


def _placement(j: ET.Element) -> pin.SE3:
    o = j.find("origin")
    xyz = np.array([float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()])
    rpy = np.array([float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()])
    return pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)


def _axis(j: ET.Element) -> np.ndarray:
    ax = j.find("axis")
    a = np.array([float(v) for v in (ax.get("xyz") if ax is not None else "1 0 0").split()])
    return a / np.linalg.norm(a)


def _joint_frames(chain: dict, oMb: pin.SE3) -> list:
    """Joint frames (root frame, m) of a folded chain at zero command, and its SMR frame last."""
    out, M = [], oMb
    for o in chain["origins"]:
        M = M * o
        out.append(M)
    out.append(M * chain["flange"] * chain["smr"])
    return out


def _fmt_mm(v) -> str:
    return "[" + ", ".join(f"{x:.4f}" for x in v) + "]"


def rewrite_urdf(text: str, tip: str, chain: dict, comments: list[str], base: str | None = None, *,
                 nominal: dict, tool_mm=None, smr_link: str = "smr", joint1_reversed: bool = False) -> tuple[str, dict]:
    """The user's URDF with the calibration folded into its revolute joints' ``<origin>`` elements.

    Every link keeps the frame the user's URDF gives it on its body: the user's link ``i`` (the child
    of revolute joint ``i``) sits at ``J_i . X_i`` where ``J_i`` is the model's joint frame and
    ``X_i = J_i_nominal^-1 . U_i`` the constant placement of the user's frame on that body in the
    nominal robot. Its origin thus changes only by the calibration's amounts (the model's frame errors,
    millimetres and arcseconds), never by a change of convention; fixed joints (``tool0``, the flange,
    a camera, the fixed base) are not touched, so every fixed child stays where the user's file puts
    it on its link. The SMR (or a 6-DoF probe's frame) is written as a new fixed child ``smr_link`` of
    ``tip`` (its origin rewritten when ``tip`` already has such a child), at the model's calibrated
    position (``jointcal_<smr_link>`` when the file has another link of that name); an SMR's frame is
    parallel to ``tip``'s, a probe's turned as the model has it.

    Parameters
    ----------
    text : str
        The user's URDF, the one the robot was imported from (``jointcal import --robot``).
    tip : str
        The link the SMR is given in (``jointcal import --tip``).
    chain, nominal : dict
        The calibrated and the nominal robot as folded chains (:func:`pipeline.export.chain.folded_chain`).
    comments : list of str
        Lines written as XML comments after the declaration.
    base : str, optional
        The link whose frame is the model's base frame (``jointcal import --base``; default the root).
    tool_mm : array_like, shape (3,), mm, optional
        The SMR in ``tip``'s frame as given to ``jointcal import --tool-mm`` (default ``tip``'s origin);
        checked against the model's nominal robot.
    smr_link : str
        Name of the SMR link written.
    joint1_reversed : bool
        The model's joint 1 angle is minus the recorded one (robot.toml's ``[coupling]`` row
        ``q1 = { q1 = -1.0 }``, which import writes for a URDF whose joint 1 turns about -z): the URDF's
        joint 1 axis may then be the model's z turned round; it is kept as the user wrote it.

    Returns
    -------
    text : str
        The rewritten URDF (every byte but the changed origins, the added SMR link and the comments kept).
    info : dict
        ``smr_link``, ``smr_mm`` (the calibrated SMR in ``tip``'s frame, mm), ``moved_mm`` and
        ``turned_arcsec`` (largest change of a revolute joint's origin).

    Raises
    ------
    ValueError
        The URDF is not the one the model's robot was derived from (a joint axis elsewhere, another
        joint count, the SMR elsewhere on ``tip``), or a link is unknown.
    """
    root = ET.fromstring(text)
    joints = _chain_joints(root, tip)
    moving = [j for j in joints if j.get("type") in ("revolute", "continuous")]
    n = len(chain["origins"])
    if len(moving) != n:
        raise UrdfProblem(f"the URDF's chain to '{tip}' has {len(moving)} revolute joints; the model has {n}", "link",
                          tip)
    pm = pin.buildModelFromXML(text)
    pdata = pm.createData()
    pin.forwardKinematics(pm, pdata, pin.neutral(pm))
    pin.updateFramePlacements(pm, pdata)
    links = {l.get("name") for l in root.findall("link")}
    if base is not None and base not in links:
        raise UrdfProblem(f"no link '{base}' in the URDF for --base")
    oMb = pdata.oMf[pm.getFrameId(base)].copy() if base is not None else pin.SE3.Identity()
    if base is not None and pm.frames[pm.getFrameId(base)].parentJoint != 0:
        raise UrdfProblem(f"base link '{base}' is not on the chain before the first revolute joint", "link", base)
    cal, nom = _joint_frames(chain, oMb), _joint_frames(nominal, oMb)
    # the user's link frames on the bodies of the model's joint frames (nominal robot, q = 0)
    user = [pdata.oMi[pm.getJointId(j.get("name"))].copy() for j in moving]
    X = []
    for i, (j, U) in enumerate(zip(moving, user)):
        Xi = nom[i].actInv(U)
        axis_in_J = Xi.rotation @ _axis(j)
        along = abs(axis_in_J[2]) if (i == 0 and joint1_reversed) else axis_in_J[2]   # a -z joint 1: -q1
        off_deg = np.rad2deg(np.arccos(np.clip(along, -1.0, 1.0)))
        off_mm = float(np.linalg.norm(Xi.translation[:2])) * 1000.0
        if off_deg > AXIS_TOL_DEG or off_mm > AXIS_TOL_MM:
            raise UrdfProblem(f"joint '{j.get('name')}' of the URDF lies {off_mm:.4g} mm / {off_deg:.4g} deg from "
                             f"joint {i + 1} of the model's robot: give the URDF the robot was imported from, with "
                             "the same --tip and --base as jointcal import", "joint", j.get("name"))
        X.append(Xi)
    # D_i: how the calibration moves body i at zero command (root frame); D_0 = identity (the fixed base)
    D = [pin.SE3.Identity()] + [(cal[i] * X[i]) * user[i].inverse() for i in range(n)]
    new_origins, moved, turned = {}, 0.0, 0.0
    for i, j in enumerate(moving):
        old = _placement(j)
        parent = user[i] * old.inverse()                  # the parent link's frame (nominal, q = 0)
        new = (D[i] * parent).actInv(D[i + 1] * user[i])
        change = old.actInv(new)
        moved = max(moved, float(np.linalg.norm(change.translation)) * 1000.0)
        turned = max(turned, float(np.linalg.norm(pin.log3(change.rotation))))
        new_origins[j.get("name")] = origin_attrs(new)
    # the SMR: a fixed child of ``tip``
    tip_nom = pdata.oMf[pm.getFrameId(tip)].copy()
    given = np.zeros(3) if tool_mm is None else np.asarray(tool_mm, float)
    smr_nom_mm = tip_nom.actInv(nom[-1]).translation * 1000.0
    if np.linalg.norm(smr_nom_mm - given) > AXIS_TOL_MM:
        said = f"--tool-mm {_fmt_mm(given)}" if tool_mm is not None else "its origin (no --tool-mm)"
        raise UrdfProblem(f"the model's robot has the SMR at {_fmt_mm(smr_nom_mm)} mm in link '{tip}''s frame, not at "
                         f"{said}: give --tip and --tool-mm as to jointcal import", "link", tip)
    tip_cal = D[n] * tip_nom
    smr = tip_cal.actInv(cal[-1])
    probe = not (np.allclose(nominal["smr"].rotation, np.eye(3), atol=1e-12)
                 and np.allclose(chain["smr"].rotation, np.eye(3), atol=1e-12))
    if not probe:
        smr = pin.SE3(np.eye(3), smr.translation)
    head = "".join(f"<!-- {c.replace('--', '-')} -->\n" for c in comments)
    out = _replace_origins(text, new_origins)
    smr_link = _free_child_name(root, tip, smr_link)
    out = _put_fixed_child(out, root, tip, smr_link, origin_attrs(smr))
    info = {"smr_link": smr_link, "smr_mm": [float(v) for v in smr.translation * 1000.0],
            "moved_mm": moved, "turned_arcsec": float(np.rad2deg(turned) * 3600.0)}
    return _insert_after_declaration(out, head), info


def rewrite_urdf_file(path, tip: str, chain: dict, comments: list[str], base: str | None = None, *, nominal: dict,
                      tool_mm=None, joint1_reversed: bool = False) -> str:
    """:func:`rewrite_urdf` on the file ``path``; a problem is an :class:`InputError` at the element it is about."""
    from ..core.errors import InputError
    from ..core.files import read_text_input
    from ..robot.campaign.urdf import tag_line

    text = read_text_input(path, "URDF")
    try:
        return rewrite_urdf(text, tip, chain, comments, base, nominal=nominal, tool_mm=tool_mm,
                            joint1_reversed=joint1_reversed)[0]
    except UrdfProblem as exc:
        line, col = tag_line(text, exc.tag, exc.name)
        if line is None:
            line, col = tag_line(text, "robot")
        raise InputError(path, str(exc), line, col) from None
    except ET.ParseError as exc:
        line, col = exc.position
        raise InputError(path, f"not valid XML: {str(exc).split(':')[0]}", line, col + 1) from None
    except (ValueError, RuntimeError) as exc:
        raise InputError(path, f"not a URDF jointcal can rewrite ({' '.join(str(exc).split())[:300]})", 1, 1) from None


def _free_child_name(root: ET.Element, parent: str, name: str) -> str:
    """``name``, or ``jointcal_<name>`` when the URDF has a link ``name`` that is not a fixed child of ``parent``."""
    for cand in (name, f"jointcal_{name}"):
        joint = next((j for j in root.findall("joint") if j.find("child").get("link") == cand), None)
        exists = any(l.get("name") == cand for l in root.findall("link"))
        if not exists or (joint is not None and joint.get("type") == "fixed"
                          and joint.find("parent").get("link") == parent):
            return cand
    raise UrdfProblem(f"the URDF has links '{name}' and 'jointcal_{name}' elsewhere than on '{parent}': rename one, "
                      "the SMR is written as that link", "link", name)


def _put_fixed_child(text: str, root: ET.Element, parent: str, child: str, origin: tuple[str, str]) -> str:
    """``child`` as a fixed child link of ``parent`` at ``origin``: its joint's origin rewritten when the URDF
    already has it (a file exported before), else a link and a fixed joint added before ``</robot>``."""
    for j in root.findall("joint"):
        if j.find("child").get("link") == child:
            if j.get("type") != "fixed" or j.find("parent").get("link") != parent:
                raise ValueError(f"the URDF has a link '{child}' that is not a fixed child of '{parent}': "
                                 "rename it, the SMR is written as that link")
            return _replace_origins(text, {j.get("name"): origin})
    if any(l.get("name") == child for l in root.findall("link")):
        raise ValueError(f"the URDF has a link '{child}' that is not a fixed child of '{parent}': rename it, the "
                         "SMR is written as that link")
    end = text.rindex("</robot>")
    indent = re.search(r"\n([ \t]*)<joint\b", text)
    ind = indent.group(1) if indent else "  "
    nl = "\r\n" if "\r\n" in text else "\n"
    xyz, rpy = origin
    block = (f"{ind}<link name=\"{child}\"/>{nl}"
             f"{ind}<joint name=\"{parent}-{child}\" type=\"fixed\">{nl}"
             f"{ind}{ind}<parent link=\"{parent}\"/>{nl}{ind}{ind}<child link=\"{child}\"/>{nl}"
             f"{ind}{ind}<origin xyz=\"{xyz}\" rpy=\"{rpy}\"/>{nl}{ind}</joint>{nl}")
    line_start = text.rfind("\n", 0, end) + 1
    if text[line_start:end].strip() == "":
        return text[:line_start] + block + text[line_start:]
    return text[:end] + nl + block + text[end:]


def _replace_origins(text: str, new: dict) -> str:
    """The text with the ``<origin>`` of each named joint element (one with a ``type``) replaced; all
    else byte for byte."""
    for name, (xyz, rpy) in new.items():
        start = None
        for m in re.finditer(r"<joint\b[^>]*>", text):
            tag = m.group(0)
            if re.search(r'\bname\s*=\s*"' + re.escape(name) + '"', tag) and re.search(r"\btype\s*=", tag):
                start = m
                break
        if start is None:
            raise ValueError(f"joint '{name}' not found in the URDF text")
        end = text.index("</joint>", start.end())
        body = text[start.end():end]
        element = f'<origin xyz="{xyz}" rpy="{rpy}"/>'
        o = re.search(r"<origin\b[^>]*?(/>|>\s*</origin>)", body)
        if o:
            body = body[:o.start()] + element + body[o.end():]
        else:
            indent = re.search(r"\n([ \t]*)<", body)
            body = f"\n{indent.group(1) if indent else '    '}{element}" + body
        text = text[:start.end()] + body + text[end:]
    return text


def _insert_after_declaration(text: str, head: str) -> str:
    decl = re.match(r"\s*<\?xml[^>]*\?>[ \t]*\n?", text)
    k = decl.end() if decl else 0
    return text[:k] + head + text[k:]
