"""``jointcal export --format urdf``: the fitted rigid chain as a URDF (contract section 8).

Geometry, base and tool are folded into the joint origins (:func:`pipeline.export.chain.folded_chain`):
joint i's origin is the placement of its axis (z) in the frame of joint i-1, its fitted zero offset a
rotation about the axis in the origin; the flange and the SMR are fixed frames after the last joint.
Numbers are written at full precision (``repr``): 6 significant digits cost several um at the tool.
rpy is URDF's roll-pitch-yaw, ``R = Rz(yaw) Ry(pitch) Rx(roll)``. ``<calibration rising>`` is not used
(pinocchio and most parsers ignore it).

With the user's own URDF (``--urdf`` and ``--tip``) only ``<origin>`` elements of the joints on the
root-to-tip chain change (:func:`rewrite_urdf`).
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
        raise ValueError(f"no link '{tip}' in the URDF (links: {', '.join(sorted(links)[:8])} …)")
    chain, link = [], tip
    while link in by_child:
        j = by_child[link]
        chain.append(j)
        link = j.find("parent").get("link")
    return chain[::-1]


def rewrite_urdf(text: str, tip: str, chain: dict, comments: list[str], base: str | None = None) -> str:
    """The user's URDF with only the ``<origin>`` elements of its root-to-``tip`` joints changed.

    The user's chain must have as many revolute/continuous joints as the model and its frames are
    kept where they are as far as possible: each revolute joint's new origin places its axis where
    the model has it, the fixed joints before the first revolute joint and between revolute joints
    are kept (folded into the next revolute joint's origin), and the fixed joints after the last
    revolute joint get the model's flange and SMR when the chain ends at the SMR (``tip`` = the SMR
    link; otherwise the model's flange goes into the last fixed joint, or the last revolute's child).
    Axes other than z are handled by a rotation that takes z onto the user's axis. ``base``: the link
    whose frame is the model's base frame (as ``jointcal import --base``; default the URDF's root);
    it must lie on the chain before the first revolute joint.
    """
    root = ET.fromstring(text)
    joints = _chain_joints(root, tip)
    moving = [j for j in joints if j.get("type") in ("revolute", "continuous")]
    n = len(chain["origins"])
    if len(moving) != n:
        raise ValueError(f"the URDF's chain to '{tip}' has {len(moving)} revolute joints; the model has {n}")

    def placement(j):
        o = j.find("origin")
        xyz = np.array([float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()])
        rpy = np.array([float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()])
        return pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)

    def axis_frame(j):
        """Rotation taking z onto the joint's axis (its frame = user frame . A, axis along A's z)."""
        ax = j.find("axis")
        a = np.array([float(v) for v in (ax.get("xyz") if ax is not None else "1 0 0").split()])
        a = a / np.linalg.norm(a)
        z = np.array([0.0, 0.0, 1.0])
        v, c = np.cross(z, a), float(z @ a)
        if np.linalg.norm(v) < 1e-12:
            R = np.eye(3) if c > 0 else pin.utils.rotate("x", np.pi)
        else:
            R = pin.exp3(v / np.linalg.norm(v) * np.arctan2(np.linalg.norm(v), c))
        return pin.SE3(R, np.zeros(3))

    new_origins = {}

    def set_origin(j, M):
        new_origins[j.get("name")] = origin_attrs(M)

    # the model's base frame in the URDF root's frame (fixed joints from the root to ``base``)
    oMb = pin.SE3.Identity()
    if base is not None and base != joints[0].find("parent").get("link"):
        for j in joints:
            if j.get("type") in ("revolute", "continuous"):
                raise ValueError(f"base link '{base}' is not on the chain before the first revolute joint")
            oMb = oMb * placement(j)
            if j.find("child").get("link") == base:
                break
    # the model's joint frames in the root frame at zero command (axis z)
    model_frames, M = [], oMb
    for o in chain["origins"]:
        M = M * o
        model_frames.append(M)
    user_link = pin.SE3.Identity()       # the user's frame of the current parent link (base: identity)
    k = 0
    fixed_since = pin.SE3.Identity()     # fixed joints between the last revolute joint and this one (kept)
    for j in joints:
        if j.get("type") in ("revolute", "continuous"):
            A = axis_frame(j)
            # user joint frame = parent_link . fixed_since . origin; its axis frame = that . A = model frame
            target = model_frames[k] * A.inverse()
            new = (user_link * fixed_since).actInv(target)
            set_origin(j, new)
            user_link = user_link * fixed_since * new
            fixed_since = pin.SE3.Identity()
            k += 1
        else:
            fixed_since = fixed_since * placement(j)
    # after the last revolute joint: the model's flange and SMR in the user's last link frame
    tail = [j for j in joints[joints.index(moving[-1]) + 1:]]
    last_axis = model_frames[-1]
    smr_world = last_axis * chain["flange"] * chain["smr"]
    if tail:
        # keep every fixed joint but the last; the last one takes the SMR where the model has it,
        # its orientation the model's flange orientation
        before = pin.SE3.Identity()
        for j in tail[:-1]:
            before = before * placement(j)
        goal = pin.SE3((last_axis * chain["flange"]).rotation, smr_world.translation)
        set_origin(tail[-1], (user_link * before).actInv(goal))
    else:
        raise ValueError(f"'{tip}' is the last revolute joint's child: add a fixed joint to the SMR (or flange) "
                         "link and give it as --tip, so that the tool can be written")
    head = "".join(f"<!-- {c.replace('--', '-')} -->\n" for c in comments)
    return _insert_after_declaration(_replace_origins(text, new_origins), head)


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
