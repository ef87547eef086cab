"""Issue 53's acceptance, reduced (the full runs: bench/acceptance_bench.py): a simulated FANUC cell
(its vendor-style URDF, coupled J2/J3, a 3-SMR nest), and the same for a KUKA and an ABB, imported as
recorded with no hand preparation, fitted, exported and a program corrected.

The true robot is hidden (tests/acceptance_cells.py: the user's URDF with its joint origins moved); the
pipeline gets the nominal URDF, the tracker's export and its map only. At the end the test compares:
- the vendor's flange link of the exported URDF (FANUC and ABB `tool0`, KUKA `flange`) with the
  truth's, in the tracker's frame, at 200 random poses: within 0.1 mm and 0.01 deg;
- a program of the vendor (FANUC .ls: Cartesian targets at UT : 0 and joint targets in the pendant's
  angles; KRL, RAPID: Cartesian targets at the null tool), corrected: the true robot lands the SMR
  within 1.25 x the model's held-out RMS + 5 um of where the program meant it.
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

import acceptance_cells as ac
from pipeline.robot.arm.kinematics import load_robot
from pipeline.robot.campaign.ingest import ingest_robot_with_frame


def run_cell(invoke, cell: str, tmp, n_measured: int, seed: int = 21) -> dict:
    """The whole job on a simulated cell; the numbers the acceptance judges."""
    c = ac.CELLS[cell]
    truth, nominal, camp, fit_path, cal = ac.simulate_and_fit(invoke, cell, tmp, n_measured, seed)
    robot = load_robot(camp / "robot.toml")
    assert bool(robot.coupling) == bool(c["coupling"])
    _, _, info = ingest_robot_with_frame(camp)
    t2b = np.array(info["tracker_to_base"])
    fit = json.loads(fit_path.read_text())
    # the exported URDF's vendor flange frame against the truth's, in the tracker's frame
    Qc = ac.arm_angles(nominal.read_text(), 200, np.random.default_rng(seed + 3))
    truth_T = ac.in_tracker(truth.poses(c["flange"], Qc))
    mm, deg = ac.apart(truth_T, np.linalg.inv(t2b) @ ac.Truth(cal.read_text()).poses(c["flange"], Qc))
    mm0, deg0 = ac.apart(truth_T, np.linalg.inv(t2b) @ ac.Truth(nominal.read_text()).poses(c["flange"], Qc))
    # frames kept: every link of the exported URDF where the nominal file puts it, but for the calibration's
    # amounts (millimetres, hundredths of a degree: no link moved to another place or turned by quarter turns)
    exported, nom = ac.Truth(cal.read_text()), ac.Truth(nominal.read_text())
    links = [f.name for f in nom.model.frames if f.type == pin.FrameType.BODY]
    kept = [ac.apart(exported.poses(name, Qc[:20]), nom.poses(name, Qc[:20])) for name in links]
    # a program written for the nominal robot, inside the joint ranges the model was fitted on
    lo, hi = np.array(fit["sampled_range"]["lower_deg"]), np.array(fit["sampled_range"]["upper_deg"])
    Qp = Qc[np.all((Qc >= lo + 2.0) & (Qc <= hi - 2.0), axis=1)][:24]
    prog = ac.program(cell, ac.Truth(nominal.read_text()), robot, robot.recorded_angles(Qp), tmp)
    r = invoke("correct", "--model", fit_path, "--program", prog, "--out", tmp / "filtered", "--max-correction-deg",
               "1", "--json", tmp / "filtered.json")
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp / "filtered.json").read_text())["targets"]
    ok = np.array([t["status"] == "ok" for t in rows])
    land = ac.landing(cell, truth, robot, t2b, prog, tmp / "filtered" / prog.name, ok)
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))      # noqa: E731
    return {"flange_mm": float(mm.max()), "flange_deg": float(deg.max()), "nominal_mm": float(mm0.max()),
            "nominal_deg": float(deg0.max()), "heldout_mm": fit["heldout"]["rms_after_mm"],
            "links_moved_mm": float(max(k[0].max() for k in kept)), "links_turned_deg": float(max(k[1].max() for k in kept)),
            "given_rms_mm": rms(land["given"]), "filtered_rms_mm": rms(land["filtered"]), "n_filtered": land["n"],
            "n_motions": len(rows), "left": [(t["line"], t["status"]) for t in rows if t["status"] != "ok"]}


@pytest.mark.parametrize("cell", ["fanuc", "kuka", "abb"])
def test_a_simulated_vendor_cell_is_fitted_exported_and_corrected(invoke, tmp_path, cell):
    res = run_cell(invoke, cell, tmp_path, n_measured=100)
    assert res["nominal_mm"] > 1.0                                           # a calibration worth doing
    assert res["links_moved_mm"] < 5.0 and res["links_turned_deg"] < 0.2, res   # the user's frames kept
    assert res["flange_mm"] < 0.1 and res["flange_deg"] < 0.01, res
    assert res["n_filtered"] >= 0.9 * res["n_motions"], res                  # the rest named (res["left"])
    assert res["given_rms_mm"] > 0.5, res
    assert res["filtered_rms_mm"] <= 1.25 * res["heldout_mm"] + 0.005, res
