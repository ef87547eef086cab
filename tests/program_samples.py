"""Sample robot programs written in each vendor's syntax, from joint values (test helper).

The generated programs are written the way the vendors' own tools write them (KRL with FOLDs and a
.dat, CRLF; RAPID with %%% header, CONST robtargets and inline targets; FANUC .ls with /ATTR, tabs
and ``.582``-style numbers; URScript with def/end); the conventions come from
pipeline.programs.conventions, whose every function is tested against scipy separately.
"""

from __future__ import annotations

import numpy as np

from pipeline.programs import conventions as cv
from pipeline.programs import ik
from pipeline.programs.flanges import vendor_flange

#: kind of the k-th target: joint PTP, Cartesian PTP, Cartesian linear, Cartesian linear
KINDS = ("joint", "ptp", "lin", "lin")


def _poses(robot, Q, tool, base, fmt):
    """TCP poses in ``base`` of joints Q (n, 6) deg, ``tool`` given in the vendor's flange frame of ``fmt``."""
    chain = ik.chain_of(robot)
    F = ik.flange(chain, np.deg2rad(Q))
    Fv = vendor_flange(robot, fmt).pose
    P = [cv.invert(base) @ f @ Fv @ tool for f in F]
    flags = ik.arm_flags(chain, Q)
    return P, flags


def _f(v, d):
    s = f"{v:.{d}f}"
    return "0." + "0" * d if float(s) == 0 else s


def krl(robot, Q, name="prog"):
    """(src, dat) texts with CRLF: tool and base inline, E6POS/E6AXIS in the .dat, inline targets."""
    tool = cv.homogeneous(cv.kuka_matrix(30.0, -20.0, 10.0), robot.tool_xyz_mm)
    base = cv.homogeneous(cv.kuka_matrix(5.0, 0.0, 0.0), [100.0, -50.0, 20.0])
    P, flags = _poses(robot, Q, tool, base, "krl")
    src = ["&ACCESS RVP", "&REL 1", f"&PARAM TEMPLATE = C:\\KRC\\Roboter\\Template\\vorgabe", "&PARAM EDITMASK = *",
           f"DEF {name}( )", ";FOLD INI;%{PE}", "  ;FOLD BASISTECH INI", "    BAS (#INITMOV,0 )", "  ;ENDFOLD",
           ";ENDFOLD (INI)", "$TOOL = {X 60.0,Y 40.0,Z 120.0,A 30.0,B -20.0,C 10.0}",
           "$BASE = {X 100.0,Y -50.0,Z 20.0,A 5.0,B 0.0,C 0.0}", "$VEL.CP = 0.5 ; m/s"]
    dat = [f"DEFDAT  {name.upper()}", ";FOLD EXTERNAL DECLARATIONS;%{PE}%MKUKATPBASIS,%CEXT,%VCOMMON,%P",
           ";FOLD BASISTECH EXT;%{PE}%MKUKATPBASIS,%CEXT,%VEXT,%P", "EXT  BAS (BAS_COMMAND  :IN,REAL  :IN )",
           ";ENDFOLD (BASISTECH EXT)", ";ENDFOLD (EXTERNAL DECLARATIONS)"]
    for k, q in enumerate(Q):
        kind = KINDS[k % 4]
        p = P[k]
        a, b, c = cv.kuka_abc(p[:3, :3])
        S = cv.kuka_status(*flags[k])
        T = cv.kuka_turn(q)
        inline = k % 7 == 5
        pos = (f"X {_f(p[0, 3], 4)},Y {_f(p[1, 3], 4)},Z {_f(p[2, 3], 4)},A {_f(a, 5)},B {_f(b, 5)},C {_f(c, 5)}")
        if kind == "joint":
            ax = ",".join(f"A{j + 1} {_f(v, 5)}" for j, v in enumerate(q))
            if inline:
                src.append(f"PTP {{AXIS: {ax}}}")
            else:
                src += [f";FOLD PTP XP{k} Vel=100 % PDAT{k} Tool[1] Base[0];%{{PE}}%R 8.3.42,%MKUKATPBASIS,%CMOVE,"
                        f"%VPTP,%P 1:PTP, 2:XP{k}, 3:, 5:100, 7:PDAT{k}", f"PTP XP{k}", ";ENDFOLD"]
                dat.append(f"DECL E6AXIS XP{k}={{{ax},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}")
        else:
            word = "PTP" if kind == "ptp" else "LIN"
            st = f",S {S},T {T}" if kind == "ptp" else f",S 'B{S:03b}',T 'B{T:06b}'"
            if inline:
                src.append(f"{word} {{{pos}{st}}} C_DIS ; inline")
            else:
                src.append(f"{word} XP{k}{' C_DIS' if kind == 'lin' else ''}")
                dat.append(f"DECL E6POS XP{k}={{{pos}{st},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}")
    src += ["PTP $POS_ACT ; stay", f"END"]
    dat.append("ENDDAT")
    return "\r\n".join(src) + "\r\n", "\r\n".join(dat) + "\r\n"


def rapid(robot, Q, name="prog"):
    """A RAPID module: tooldata and wobjdata declared, CONST robtargets/jointtargets and inline ones."""
    tool = cv.homogeneous(cv.abb_matrix(0.9238795325, 0.0, 0.3826834324, 0.0), robot.tool_xyz_mm)
    uf = cv.homogeneous(cv.abb_matrix(0.9961946981, 0.0, 0.0, 0.0871557427), [100.0, -50.0, 20.0])
    P, flags = _poses(robot, Q, tool, uf, "rapid")
    tq = cv.abb_quaternion(tool[:3, :3])
    wq = cv.abb_quaternion(uf[:3, :3])
    head = ["%%%", "  VERSION:1", "  LANGUAGE:ENGLISH", "%%%", "", f"MODULE {name}",
            "  ! hand-written sample (tests/program_samples.py)",
            f"  PERS tooldata tSMR:=[TRUE,[[{robot.tool_xyz_mm[0]:.1f},{robot.tool_xyz_mm[1]:.1f},"
            f"{robot.tool_xyz_mm[2]:.1f}],[{tq[0]:.10f},{tq[1]:.10f},{tq[2]:.10f},{tq[3]:.10f}]],"
            "[60,[0,0,100],[1,0,0,0],0,0,0]];",
            f"  TASK PERS wobjdata wCell:=[FALSE,TRUE,\"\",[[100,-50,20],[{wq[0]:.10f},{wq[1]:.10f},{wq[2]:.10f},"
            f"{wq[3]:.10f}]],[[0,0,0],[1,0,0,0]]];"]
    decl, body = [], ["  PROC main()", "    ConfJ \\On;"]
    for k, q in enumerate(Q):
        kind = KINDS[k % 4]
        p = P[k]
        qq = cv.abb_quaternion(p[:3, :3])
        cf = cv.abb_quadrants(q)
        cfx = cv.abb_cfx(*flags[k])
        inline = k % 7 == 5
        if kind == "joint":
            lit = f"[[{','.join(_f(v, 5) for v in q)}],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]"
            if inline:
                body.append(f"    MoveAbsJ {lit}\\NoEOffs,v1000,fine,tSMR\\WObj:=wCell;")
            else:
                decl.append(f"  CONST jointtarget j{k}:={lit};")
                body.append(f"    MoveAbsJ j{k},v1000,z50,tSMR;")
        else:
            lit = (f"[[{_f(p[0, 3], 3)},{_f(p[1, 3], 3)},{_f(p[2, 3], 3)}],[{','.join(_f(v, 8) for v in qq)}],"
                   f"[{cf[0]},{cf[1]},{cf[2]},{cfx}],[9E9,9E9,9E9,9E9,9E9,9E9]]")
            word = "MoveJ" if kind == "ptp" else "MoveL"
            if inline:
                body.append(f"    {word} {lit},v500,z10,tSMR\\WObj:=wCell;")
            else:
                decl.append(f"  CONST robtarget p{k}:={lit};")
                body.append(f"    {word} p{k}, v500, fine, tSMR \\WObj:=wCell;  ! to p{k}")
    body += ["    MoveL Offs(p1,0,0,50),v100,fine,tSMR\\WObj:=wCell;", "  ENDPROC", "ENDMODULE"]
    return "\n".join(head + decl + [""] + body) + "\n"


def fanuc(robot, Q, name="PROG"):
    """A FANUC .ls: UF : 0, UT : 1 (--tool), J and L moves, joint and Cartesian /POS entries."""
    tool = cv.homogeneous(cv.fanuc_matrix(10.0, -20.0, 30.0), robot.tool_xyz_mm)
    P, flags = _poses(robot, Q, tool, np.eye(4), "fanuc")

    def num(v, d=3):
        s = f"{v:{9}.{d}f}"
        return s.replace("0.", " .", 1) if abs(v) < 1 and not s.strip().startswith("-") else (
            s.replace("-0.", " -.", 1) if abs(v) < 1 else s)

    mn, pos = [], []
    for k, q in enumerate(Q):
        kind = KINDS[k % 4]
        i = k + 1
        word = "J" if kind in ("joint", "ptp") else "L"
        speed = "100%" if word == "J" else "250mm/sec"
        mn.append(f"{i:4d}:{word} P[{i}{':' + chr(34) + 'app' + chr(34) if k == 3 else ''}] {speed} "
                  f"{'FINE' if k % 2 else 'CNT50'}    ;".replace(chr(34), ""))
        head = f"P[{i}:\"app\"]{{" if k == 3 else f"P[{i}]{{"
        if kind == "joint":
            pos += [head, "   GP1:", "\tUF : 0, UT : 1,\t",
                    f"\tJ1= {num(q[0])} deg,\tJ2= {num(q[1])} deg,\tJ3= {num(q[2])} deg,",
                    f"\tJ4= {num(q[3])} deg,\tJ5= {num(q[4])} deg,\tJ6= {num(q[5])} deg", "};"]
        else:
            p = P[k]
            w, pp, r = cv.fanuc_wpr(p[:3, :3])
            t = cv.fanuc_turns(q)
            pos += [head, "   GP1:",
                    f"\tUF : 0, UT : 1,\t\tCONFIG : '{cv.fanuc_letters(*flags[k])}, {t[0]}, {t[1]}, {t[2]}',",
                    f"\tX = {num(p[0, 3])}  mm,\tY = {num(p[1, 3])}  mm,\tZ = {num(p[2, 3])}  mm,",
                    f"\tW = {num(w)} deg,\tP = {num(pp)} deg,\tR = {num(r)} deg", "};"]
    n = len(Q)
    mn.insert(2, f"{3:4d}:  !hand-written sample ;")
    mn = [f"{k + 1:4d}:{line.split(':', 1)[1]}" for k, line in enumerate(mn)]
    mn.append(f"{n + 2:4d}:L PR[1] 100mm/sec FINE    ;")
    lines = [f"/PROG  {name}", "/ATTR", "OWNER\t\t= MNEDITOR;", "COMMENT\t\t= \"\";", f"LINE_COUNT\t= {n + 2};",
             "DEFAULT_GROUP\t= 1,*,*,*,*;", "/APPL", "/MN"] + mn + ["/POS"] + pos + ["/END"]
    return "\n".join(lines) + "\n"


def urscript(robot, Q, name="prog"):
    """A URScript: set_tcp, movej joint lists, movel/movej poses, global pose variables."""
    tool = cv.homogeneous(cv.ur_matrix(0.1, -0.2, 0.3), robot.tool_xyz_mm)
    P, _ = _poses(robot, Q, tool, np.eye(4), "ur")
    tv = np.array(robot.tool_xyz_mm) / 1000.0
    lines = [f"def {name}():", "  # hand-written sample (tests/program_samples.py)",
             f"  set_tcp(p[{tv[0]:.6f}, {tv[1]:.6f}, {tv[2]:.6f}, 0.1, -0.2, 0.3])"]
    for k, q in enumerate(Q):
        kind = KINDS[k % 4]
        if kind == "joint":
            lines.append(f"  movej([{', '.join(f'{v:.9f}' for v in np.deg2rad(q))}], a=1.4, v=1.05)")
        else:
            p = P[k]
            rv = cv.ur_rotvec(p[:3, :3])
            lit = f"p[{', '.join(f'{v:.9f}' for v in np.r_[p[:3, 3] / 1000.0, rv])}]"
            if k % 7 == 5:
                lines.append(f"  global Waypoint_{k}_p={lit}")
                lines.append(f"  movej(get_inverse_kin(Waypoint_{k}_p), a=1.4, v=1.05)")
            else:
                lines.append(f"  {'movej' if kind == 'ptp' else 'movel'}({lit}, a=1.2, v=0.25, r=0)")
    lines += ["  movel(pose_add(get_actual_tcp_pose(), p[0, 0, 0.05, 0, 0, 0]), a=1.2, v=0.25)", "end", f"{name}()"]
    return "\n".join(lines) + "\n"


def smooth_path(robot, Q, n):
    """``n`` of the joint vectors Q (m, 6) deg on one branch (the commonest), far from its
    singularities, in a nearest-neighbour order: a program a controller runs without a branch change."""
    chain = ik.chain_of(robot)
    F = ik.frames(chain, np.deg2rad(Q))
    v = ik._flag_values(F)
    code = (v < 0) @ np.array([1, 2, 4])
    scale = np.abs(v).max(axis=0)
    margin = np.min(np.abs(v) / scale, axis=1)
    Q = Q[(code == np.bincount(code).argmax()) & (margin > 0.1)]
    order = [0]
    left = list(range(1, len(Q)))
    while left and len(order) < n:
        d = np.abs(Q[left] - Q[order[-1]]).max(axis=1)
        order.append(left.pop(int(np.argmin(d))))
    return Q[order]
