"""What programs other people published showed (session 57; the table is in docs/programs.md, "Programs
others published"). Every program text here is synthetic, written for the test: a published program is
never copied into the project. Each test failed on the code before its fix."""

from __future__ import annotations

import re

from pipeline.programs import fanuc, krl, rapid, urscript

FANUC_EN = """/PROG  WELD1
/ATTR
OWNER\t\t= MNEDITOR;
COMMENT\t\t= "synthetic";
DEFAULT_GROUP\t= 1,*,*,*,*;
/MN
   1:  UFRAME_NUM=0 ;
   2:  UTOOL_NUM=0 ;
   3:J P[1] 100% FINE    ;
   4:J P[2] 100% CNT100    ;
   5:L P[3] 500mm/sec FINE    ;
   6:L P[3] 500mm/sec FINE Tool_Offset,PR[1]    ;
/POS
P[1]{
   GP1:
\tUF : 0, UT : 0,\t\tCONFIG : 'N D B, 0, 0, 1',
\tX =  1200.000  mm,\tY =   300.000  mm,\tZ =   900.000  mm,
\tW =   180.000 deg,\tP =     0.000 deg,\tR =     0.000 deg
};
P[2]{
   GP1:
\tUF : 0, UT : 0,\t\tCONFIG : 'F U T, -1, 0, 0',
\tX =  1100.000  mm,\tY =  -200.000  mm,\tZ =   800.000  mm,
\tW =   170.000 deg,\tP =    10.000 deg,\tR =     5.000 deg
};
P[3]{
   GP1:
\tUF : 0, UT : 0,\t\tCONFIG : 'F U T, 0, 0, 0',
\tX =  1100.000  mm,\tY =  -200.000  mm,\tZ =   700.000  mm,
\tW =   170.000 deg,\tP =    10.000 deg,\tR =     5.000 deg
};
/END
"""

# the same program as a FANUC controller set to German writes it: KONFIG, BENUTZER_NUM, WKZ_NUM, mm/sek
FANUC_DE = (FANUC_EN.replace("OWNER\t\t= MNEDITOR", "EIGN.\t\t= MNEDITOR").replace("COMMENT", "KOMMENTAR")
            .replace("UFRAME_NUM", "BENUTZER_NUM").replace("UTOOL_NUM", "WKZ_NUM").replace("CONFIG :", "KONFIG :")
            .replace("mm/sec", "mm/sek").replace("DEFAULT_GROUP", "DEFAULT_GRUP").replace("Tool_Offset", "WKZ_Offset"))


def test_fanuc_configuration_in_the_pendants_language(tmp_path):
    """A controller set to German writes ``KONFIG : '...'``: it was not read (no branch, no turns), so
    a J move went to the branch of the point before and the German file was filtered to other
    numbers than the same program in English (a published German TP backup and its English twin). Its
    tool offset option is ``WKZ_Offset`` (was not seen: the motion would have been filtered)."""
    (tmp_path / "en.ls").write_text(FANUC_EN)
    (tmp_path / "de.ls").write_bytes(FANUC_DE.encode("latin-1"))
    en, de = fanuc.read(tmp_path / "en.ls").targets, fanuc.read(tmp_path / "de.ls").targets
    assert [t.flags for t in en] == [(True, True, True)] + [(False, False, False)] * 3
    assert [t.turn for t in en] == [(0, 0, 1), (-1, 0, 0), (0, 0, 0), (0, 0, 0)]
    assert [bool(t.runtime) for t in en] == [False, False, False, True]
    assert [(t.flags, t.turn, t.branch, bool(t.runtime)) for t in de] == [
        (t.flags, t.turn, t.branch, bool(t.runtime)) for t in en]


def test_fanuc_coordinated_motion_is_left_as_given(tmp_path):
    """``COORD`` (coordinated motion): the point is in a frame the leader group (a positioner) moves,
    so the robot's joints depend on the positioner's axes too. It was filtered as if the user frame
    stood still (a published weld program on a two-axis positioner)."""
    s = FANUC_EN.replace("   4:J P[2] 100% CNT100    ;", "   4:J P[2] 100% CNT100 COORD    ;").replace(
        "   5:L P[3] 500mm/sec FINE    ;", "   5:L P[3] 50cm/min CNT100 COORD PTH  ;")
    (tmp_path / "c.ls").write_text(s)
    t = fanuc.read(tmp_path / "c.ls").targets
    assert not t[0].runtime
    assert all("COORD" in x.runtime and "positioner" in x.runtime for x in t[1:3]), [x.runtime for x in t]


KRL_SRC = """DEF follow( )
  $TOOL = $NULLFRAME
  $BASE = $NULLFRAME
  RET = EKI_GetReal("Channel", "Pos/X", goal.X)
  RET = EKI_GetFrame("Channel", "Pos", whole)
  show(shown)
  LIN goal
  LIN whole
  PTP shown
  LIN fixed
END

DEF show(p :IN)
  DECL E6POS p
END
"""
KRL_DAT = """DEFDAT follow
  DECL EKI_STATUS RET
  DECL E6POS goal={X 1500.0,Y 100.0,Z 1600.0,A 0.0,B 60.0,C 0.0,S 2,T 35}
  DECL FRAME whole={X 1500.0,Y 100.0,Z 1500.0,A 0.0,B 60.0,C 0.0}
  DECL E6POS shown={X 1400.0,Y 100.0,Z 1500.0,A 0.0,B 60.0,C 0.0,S 2,T 35}
  DECL E6POS fixed={X 1500.0,Y 100.0,Z 1400.0,A 0.0,B 60.0,C 0.0,S 2,T 35}
ENDDAT
"""


def test_krl_variable_a_call_writes_is_left_as_given(tmp_path):
    """A point passed to a function (EthernetKRL's ``EKI_GetReal(..., goal.X)``, a KRL parameter is
    :OUT unless declared :IN) holds what the call wrote at run time: it was filtered from its DECL
    (a published EKI server program). A point passed to a routine of the file that declares the
    parameter :IN, and a point passed nowhere, are still read from their DECL."""
    (tmp_path / "follow.src").write_text(KRL_SRC)
    (tmp_path / "follow.dat").write_text(KRL_DAT)
    named = {t.name: t for t in krl.read(tmp_path / "follow.src").targets}
    assert "EKI_GetReal" in named["goal"].runtime and "line 4" in named["goal"].runtime
    assert "EKI_GetFrame" in named["whole"].runtime
    assert not named["shown"].runtime and not named["fixed"].runtime


def test_urscript_qnear_picks_the_solution_the_controller_picks(tmp_path):
    """PolyScope writes every waypoint as ``movej(get_inverse_kin(Waypoint_1_p, qnear=Waypoint_1_q))``:
    the controller goes to the solution nearest qnear. It was not read (the solution nearest the point
    before was taken: another branch than the taught one on a published PolyScope program). Two motions
    to one pose, each with the qnear of another of its solutions, go to those two solutions."""
    import numpy as np

    import program_samples as ps
    from conftest import ROOT
    from pipeline.programs import conventions as cv
    from pipeline.programs import ik
    from pipeline.programs.filtering import play
    from pipeline.robot.arm.kinematics import load_robot

    robot = load_robot(ROOT / "raw/real/ur10-ipa/robot.toml")
    chain = ik.chain_of(robot)
    q0 = (robot.lower_deg + robot.upper_deg) / 2 + np.array([20.0, -30.0, 40.0, 10.0, 35.0, -15.0])
    T = ik.flange(chain, np.deg2rad(q0[None]))[0]
    sols = np.rad2deg(ik.expand_turns(chain, ik.solve_all(chain, T[None])[0]))
    far = sols[np.argmax(np.abs(sols - q0).max(axis=1))]        # another solution of the same pose
    assert np.abs(far - q0).max() > 30.0
    tool = np.eye(4)
    P, _ = ps._poses(robot, q0[None], tool, np.eye(4), "ur")
    lit = "p[" + ", ".join(f"{v:.12f}" for v in np.r_[P[0][:3, 3] / 1000.0, cv.ur_rotvec(P[0][:3, :3])]) + "]"
    near = lambda q: "[" + ", ".join(f"{v:.6f}" for v in np.deg2rad(q + 2.0)) + "]"   # noqa: E731
    text = (f"def taught():\n  set_tcp(p[0.0, 0.0, 0.0, 0.0, 0.0, 0.0])\n  global Waypoint_1_p={lit}\n"
            f"  global Waypoint_1_q={near(q0)}\n  movej(get_inverse_kin(Waypoint_1_p, qnear=Waypoint_1_q), a=1.4, v=1.05)\n"
            f"  movej(get_inverse_kin(Waypoint_1_p, {near(far)}), a=1.4, v=1.05)\n"
            f"  movej(get_inverse_kin(Waypoint_1_p, qnear=Waypoint_1_q), a=1.4, v=1.05)\nend\n")
    (tmp_path / "taught.script").write_text(text)
    prog = urscript.read(tmp_path / "taught.script")
    played = play(prog, robot)
    assert not any(played.reason), played.reason
    assert np.allclose(played.q_deg[0], q0, atol=1e-6) and np.allclose(played.q_deg[2], q0, atol=1e-6)
    assert np.allclose(played.q_deg[1], far, atol=1e-6)


RAPID_TEACH = """MODULE Teach
  PERS Wobjdata wTeach:=[FALSE,TRUE,"",[[1000,-300,200],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];
  PERS wobjdata wFixed:=[FALSE,TRUE,"",[[1000,300,200],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];
  PERS robjoint jNow:=[0,0,0,0,30,0];
  PROC main()
    CONST robtarget pA:=[[100,0,300],[0,0,1,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
    wteach.oframe:=[[0,0,0],[1,0,0,0]];
    MoveAbsJ [jNow,[9e9,9e9,9e9,9e9,9e9,9e9]], v100, fine, tool0;
    MoveJ pA,v1000,fine,tool0\\WObj:=wTeach;
    MoveJ pA,v1000,fine,tool0\\WObj:=wFixed;
  ENDPROC
ENDMODULE"""


def test_rapid_aggregate_of_variables_and_a_work_object_the_program_sets(tmp_path):
    """``MoveAbsJ [joints,[9e9,...]]`` (a jointtarget of a PERS robjoint: valid RAPID) was refused as a
    broken program (exit 2: 'expected 6 numbers'), and a target in a work object whose frame the program
    sets (``wTeach.oframe := ...``, RAPID names in any case) was filtered in its declared frame (two
    published ABB modules: a controller backup's, a work-object teaching routine)."""
    (tmp_path / "Teach.mod").write_text(RAPID_TEACH)
    t = rapid.read(tmp_path / "Teach.mod").targets
    assert "built at run time" in t[0].runtime
    assert "wTeach is assigned by the program" in (t[1].runtime or "")
    assert not t[2].runtime


def test_fanuc_motion_lines_without_their_numbers_and_remote_tcp_points(tmp_path):
    """A TP listing whose /MN lines carry no number (``    :J P[1] 100% FINE ;``, as in a published
    backup's download folder) had no motion read: its targets were neither filtered nor named. A point
    taught with Remote TCP (``RX = ... mm``: the tool stands still) refused the whole program (exit 2,
    'group 1 has neither X, Y, Z, W, P, R nor J1 .. J6'), and so did a point never taught (``X = ********``)."""
    unnumbered = re.sub(r"(?m)^ +\d+:", "    :", FANUC_EN)
    (tmp_path / "u.ls").write_text(unnumbered)
    (tmp_path / "n.ls").write_text(FANUC_EN)
    u, n = fanuc.read(tmp_path / "u.ls").targets, fanuc.read(tmp_path / "n.ls").targets
    assert [(t.name, t.line, t.flags, bool(t.runtime)) for t in u] == [(t.name, t.line, t.flags, bool(t.runtime)) for t in n]
    assert len(u) == 4
    r = _fanuc_variant(tmp_path, "r.ls",
                       "\tX =  1100.000  mm,\tY =  -200.000  mm,\tZ =   800.000  mm,\n\tW =   170.000 deg,"
                       "\tP =    10.000 deg,\tR =     5.000 deg",
                       "\tRX =  1100.000  mm,\tRY =  -200.000  mm,\tRZ =   800.000  mm,\n\tRW =   170.000 deg,"
                       "\tRP =    10.000 deg,\tRR =     5.000 deg")
    assert "Remote TCP" in r[1].runtime and not r[0].runtime
    # a point never taught: the pendant writes asterisks (it refused the program too)
    t = _fanuc_variant(tmp_path, "t.ls",
                       "UF : 0, UT : 0,\t\tCONFIG : 'F U T, 0, 0, 0',\n\tX =  1100.000  mm,\tY =  -200.000  mm,"
                       "\tZ =   700.000  mm,\n\tW =   170.000 deg,\tP =    10.000 deg,\tR =     5.000 deg",
                       "UF : F, UT : F,\t\tCONFIG : 'N D B, 0, 0, 0',\n\tX = ********  mm,\tY = ********  mm,"
                       "\tZ = ********  mm,\n\tW = ******** deg,\tP = ******** deg,\tR = ******** deg")
    assert "not taught" in t[2].runtime and "not taught" in t[3].runtime and not t[0].runtime


def _fanuc_variant(tmp_path, name, old, new):
    """The targets of FANUC_EN with ``old`` replaced by ``new`` (which must occur), read from ``tmp_path/name``."""
    text = FANUC_EN.replace(old, new)
    assert text != FANUC_EN
    (tmp_path / name).write_text(text)
    return fanuc.read(tmp_path / name).targets


def test_rapid_run_time_target_is_named_whole(tmp_path):
    """A run-time target with an optional argument inside it (``Offs(CRobT(\\Tool:=tGrip), ...)``) was
    named by its text up to the backslash (``Offs(CRobT(``, a published backup's jogging routine)."""
    (tmp_path / "Jog.mod").write_text("MODULE Jog\n  PROC main()\n    MoveL Offs(CRobT(\\Tool:=tool0), 0, 0, 10)\\ID:=3, "
                                      "v100, fine, tool0;\n  ENDPROC\nENDMODULE\n")
    t = rapid.read(tmp_path / "Jog.mod").targets
    assert t[0].runtime and "Offs(CRobT(\\Tool:=tool0), 0, 0, 10)" in t[0].runtime, t[0].runtime


RAPID_TRACK = """MODULE Track
  CONST robtarget pHome:=[[900,0,1200],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  CONST robtarget pFar:=[[2400,-80,950],[0,0,1,0],[-1,0,0,0],[3100,9E9,9E9,9E9,9E9,9E9]];
  PROC main()
    MoveJ pHome, v1000, z50, tool0;
    MoveJ pFar, v1000, z50, tool0;
    MoveL [[2450,-80,950],[0,0,1,0],[-1,0,0,0],[3100,9E9,9E9,9E9,9E9,9E9]], v200, fine, tool0;
    MoveJ pFar, v1000, fine, tool0;
  ENDPROC
ENDMODULE
"""


def test_rapid_target_that_sets_an_external_axis_is_named(tmp_path):
    """A robot on a track (a published MultiMove cell: targets in world coordinates, the track's position in
    eax_a, 73-3400 mm): its targets were played without the track and reported 'no solution' without naming
    it. A Cartesian target that sets an external axis is left as given and says so; a declared one counts as
    used (not also 'declared, and no motion goes there'); 9E9 (not used) changes nothing."""
    (tmp_path / "Track.mod").write_text(RAPID_TRACK)
    t = rapid.read(tmp_path / "Track.mod").targets
    assert [x.name for x in t][:1] == ["pHome"] and not t[0].runtime
    track = [x for x in t if x.runtime]
    assert len(track) == 3 and len(t) == 4
    assert all("eax_a = 3100" in x.runtime and "external axis" in x.runtime for x in track)


def test_rapid_unclosed_bracket_is_named_as_such(tmp_path):
    """An unbalanced bracket in a RAPID statement was reported as 'statement without its ;' (the right line,
    the wrong words: a published backup's corrupted line): the ';' is there, the bracket is not closed."""
    import pytest

    from pipeline.core.errors import InputError

    text = RAPID_TRACK.replace("MoveJ pHome, v1000, z50, tool0;",
                               "MoveL [[2450,-80,950],[0,0,1,0],[-1,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9], v200, fine, tool0;")
    assert text != RAPID_TRACK
    (tmp_path / "Broken.mod").write_text(text)
    with pytest.raises(InputError) as err:
        rapid.read(tmp_path / "Broken.mod")
    assert "unbalanced brackets" in str(err.value) and ":5" in str(err.value)
    missing = RAPID_TRACK.replace("MoveJ pHome, v1000, z50, tool0;", "MoveJ pHome, v1000, z50, tool0")
    (tmp_path / "Missing.mod").write_text(missing)
    with pytest.raises(InputError) as err:
        rapid.read(tmp_path / "Missing.mod")
    assert "without its ';'" in str(err.value)
