"""`jointcal plan` (contract section 9): planned poses against random ones on the virtual cell,
parameters a pool cannot identify, --campaign, --reveal, bad pools."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.core.spec import load_spec
from pipeline.plan.design import plan_poses, pool_data, visiting_order, path_cost
from pipeline.robot.model.estimate import fit_effects
from pipeline.robot.arm.kinematics import load_robot
from pipeline.robot.arm.kinematics import directions_from_sequence
from pipeline.robot.cell.simulate import ROBOT_FIXTURE, draw_poses, make_cell

ROOT = Path(__file__).resolve().parents[1]
KR210 = ROOT / "raw" / "robot" / "kr210" / "robot.toml"
SPEC = ROOT / "specs" / "robot_kinematic.toml"
ONE_LINE = re.compile(r"^jointcal: error: (?P<file>[^:]+):(?P<line>\d+|-):(?P<col>[^:]+): \S.*$")


@pytest.fixture(scope="module")
def cell():
    robot = load_robot(KR210)
    return robot, make_cell(robot)


def _pool(robot, cell, n, seed):
    return draw_poses(robot, n, np.random.default_rng(seed), [1200.0, 1600.0, 1200.0], 30.0, cell.model_nominal)


def _measured(robot, cell, q, seed):
    rng = np.random.default_rng(seed)
    pay = np.full(len(q), ROBOT_FIXTURE["payload_kg"])
    d = directions_from_sequence(q, start_deg=(robot.lower_deg + robot.upper_deg) / 2)
    data = pool_data(robot, q, pay, d)
    data.measured_mm = cell.measure(cell.open_loop(q, d, pay, rng), rng)
    return data


def _write_pool(path, q, ids=None, extra=None):
    df = pd.DataFrame({"point_id": ids if ids is not None else [f"P{k:04d}" for k in range(len(q))]})
    for j in range(q.shape[1]):
        df[f"q{j + 1}"] = q[:, j]
    for k, v in (extra or {}).items():
        df[k] = v
    df.to_csv(path, index=False)


def test_planned_poses_beat_the_median_random_draw_on_the_virtual_cell(cell):
    robot, c = cell
    spec = load_spec(SPEC)
    Q = _pool(robot, c, 300, 5)
    test = _measured(robot, c, _pool(robot, c, 150, 6), 1)

    def heldout(q, seed):
        m = fit_effects(robot, spec.effects, _measured(robot, c, q, seed))
        assert m.converged_
        return float(np.sqrt(np.mean(np.sum((m.predict(test) - test.measured_mm) ** 2, axis=1))))

    K = 15
    plan = plan_poses(robot, spec.effects, pool_data(robot, Q, np.full(len(Q), ROBOT_FIXTURE["payload_kg"])), K)
    assert len(set(plan.chosen.tolist())) == K
    planned = heldout(Q[plan.chosen], 2)
    rng = np.random.default_rng(7)
    random = [heldout(Q[rng.choice(len(Q), K, replace=False)], 10 + i) for i in range(7)]
    assert planned < np.median(random), (planned, random)
    # the predicted error falls with the number of poses
    curve = [p["predicted_rms_mm"] for p in plan.curve if p["predicted_rms_mm"] is not None]
    assert len(curve) >= 3 and all(a > b for a, b in zip(curve, curve[1:]))


def test_visiting_order_shortens_the_path():
    rng = np.random.default_rng(0)
    # five joints (nothing assumes six): poses along a line in joint space, shuffled, plus a little noise;
    # the shortest path from one end walks the line once
    t = rng.permutation(np.linspace(0.0, 1.0, 40))
    q = np.outer(t, [90.0, -60.0, 120.0, 30.0, -45.0]) + rng.normal(0, 0.5, (40, 5))
    start = np.zeros(5)
    order = visiting_order(q, start)
    assert sorted(order.tolist()) == list(range(40))
    assert path_cost(q, order, start) < 1.1 * 120.0 + 40 * 2.0
    assert path_cost(q, order, start) < 0.1 * path_cost(q, np.arange(40), start)


def test_a_parameter_the_pool_cannot_identify_is_reported(cell, tmp_path, invoke):
    robot, c = cell
    Q = _pool(robot, c, 200, 8)
    full, frozen = tmp_path / "full.csv", tmp_path / "frozen.csv"
    _write_pool(full, Q)
    Qf = Q.copy()
    Qf[:, 3:] = Qf[0, 3:]                      # the wrist never moves: its parameters fold together
    _write_pool(frozen, Qf)
    out = {}
    for name, pool in (("full", full), ("frozen", frozen)):
        res = invoke("plan", "--robot", KR210, "--spec", SPEC, "--pool", pool, "--n", 20,
                     "--out", tmp_path / f"{name}.plan.csv", "--json", tmp_path / f"{name}.json")
        assert res.exit_code == 0, res.output
        out[name] = (json.loads((tmp_path / f"{name}.json").read_text()), res.stderr)
    js_full, js_frozen = out["full"][0], out["frozen"][0]
    lost = set(js_frozen["not_identifiable_on_pool"]) - set(js_full["not_identifiable_on_pool"])
    assert lost, "freezing the wrist must cost identifiable parameters"
    assert js_frozen["parameters_identifiable"] < js_full["parameters_identifiable"]
    assert any(name in out["frozen"][1] for name in lost)          # named on the console
    for key in ("n", "criterion", "parameters_identifiable", "predicted_rms_mm"):
        assert key in js_full
    assert js_full["n"] == 20 and js_full["predicted_rms_mm"] > 0


def test_campaign_never_repeats_a_measured_pose(cell, tmp_path, invoke):
    robot, c = cell
    Q = _pool(robot, c, 120, 9)
    meas = _measured(robot, c, Q[:30], 3)
    camp = tmp_path / "camp"
    camp.mkdir()
    (camp / "robot.toml").write_text(KR210.read_text())
    ids = [f"M{k:03d}" for k in range(30)]
    poses = pd.DataFrame({"point_id": ids, "set": "sample"})
    for j in range(6):
        poses[f"q{j + 1}"] = Q[:30, j]
    poses.to_csv(camp / "poses.csv", index=False)
    pd.DataFrame({"point_id": ids, "x_mm": meas.measured_mm[:, 0], "y_mm": meas.measured_mm[:, 1],
                  "z_mm": meas.measured_mm[:, 2]}).to_csv(camp / "tracker.csv", index=False)
    # the pool holds the measured poses again: under their own ids and under new ones
    pool = tmp_path / "pool.csv"
    again = Q[:30] + np.random.default_rng(1).uniform(-5e-5, 5e-5, (30, 6))     # as another file rounds them
    _write_pool(pool, np.vstack([Q, again]), ids + [f"P{k:04d}" for k in range(30, 120)] + [f"N{k}" for k in range(30)])
    # more poses asked for than the pool has new ones: only the 90 new ones may come
    res = invoke("plan", "--robot", KR210, "--spec", SPEC, "--pool", pool, "--n", 100, "--campaign", camp,
                 "--out", tmp_path / "plan.csv", "--json", tmp_path / "plan.json")
    assert res.exit_code == 0, res.output
    plan = pd.read_csv(tmp_path / "plan.csv")
    assert len(plan) == 90 and not set(plan["point_id"]) & set(ids)
    assert "only 90 distinct poses not yet measured" in res.stderr
    planned = plan[[f"q{j}" for j in range(1, 7)]].to_numpy()
    assert np.abs(planned[:, None, :] - Q[None, :30, :]).max(axis=2).min() > 1e-3
    assert json.loads((tmp_path / "plan.json").read_text())["campaign_poses"] == 30


def test_reveal_backlash_writes_both_directions(cell, tmp_path, invoke):
    robot, c = cell
    pool = tmp_path / "pool.csv"
    _write_pool(pool, _pool(robot, c, 80, 11))
    res = invoke("plan", "--robot", KR210, "--spec", SPEC, "--pool", pool, "--n", 24,
                 "--reveal", 'name = "backlash", joints = [4]', "--out", tmp_path / "plan.csv",
                 "--json", tmp_path / "plan.json")
    assert res.exit_code == 0, res.output
    plan = pd.read_csv(tmp_path / "plan.csv")
    assert set(plan["dir4"]) == {-1, 1} and plan["point_id"].is_unique
    js = json.loads((tmp_path / "plan.json").read_text())
    assert js["criterion"] == "Ds-optimal" and js["reveal"]["revealable"]


@pytest.mark.parametrize("edit, line, col, words", [
    (lambda df: df.drop(columns=["q6"]), "1", "q6", ["5 joint columns", "6 joints"]),
    (lambda df: df.assign(q7=0.0), "1", "q7", ["7 joint columns", "6 joints"]),
    (lambda df: df.astype({"q3": object}).assign(q3=lambda d: d["q3"].where(d.index != 4, "abc")), "6", "q3",
     ["number"]),
    (lambda df: df.assign(point_id=["A"] * len(df)), "3", "point_id", ["already"]),
    (lambda df: df.assign(q2=500.0), "2", "q2", ["range"]),
])
def test_bad_pools_are_refused(cell, tmp_path, invoke, edit, line, col, words):
    robot, c = cell
    pool = tmp_path / "pool.csv"
    _write_pool(pool, _pool(robot, c, 12, 12))
    edit(pd.read_csv(pool)).to_csv(pool, index=False)
    out = tmp_path / "plan.csv"
    res = invoke("plan", "--robot", KR210, "--spec", SPEC, "--pool", pool, "--n", 5, "--out", out)
    assert res.exit_code == 2
    msg = res.stderr.strip()
    m = ONE_LINE.match(msg)
    assert m and "\n" not in msg, msg
    assert (m["file"], m["line"], m["col"]) == (str(pool), line, col), msg
    assert all(w in msg for w in words), msg
    assert not out.exists() and not list(tmp_path.glob(".plan.csv*"))


def test_payloads_are_visited_together():
    rng = np.random.default_rng(3)
    q = rng.uniform(-90, 90, (30, 4))          # four joints
    pay = np.repeat([0.0, 10.0, 20.0], 10)[rng.permutation(30)]
    order = visiting_order(q, payload_kg=pay)
    assert np.count_nonzero(np.diff(pay[order])) == 2


@pytest.mark.parametrize("kind", ["D", "Ds", "I"])
def test_exchange_ends_where_no_single_swap_improves(kind):
    """The rank-3 updates give the criterion's true change: checked against direct determinants."""
    from pipeline.plan import design

    rng = np.random.default_rng(1)
    A = rng.normal(size=(50, 3, 8))
    M0 = 1e-9 * np.eye(8)
    W = np.einsum("nkp,nkq->pq", A, A) / len(A)
    sub = np.arange(5) if kind == "Ds" else None

    def value(S):
        M = M0 + np.einsum("nkp,nkq->pq", A[S], A[S])
        if kind == "I":
            return -np.trace(W @ np.linalg.inv(M))
        v = np.linalg.slogdet(M)[1]
        return v - (design.DS_WEIGHT * np.linalg.slogdet(M[np.ix_(sub, sub)])[1] if sub is not None else 0.0)

    crit = design._Criterion(A, M0, sub, design.DS_WEIGHT if sub is not None else 1.0)
    chosen, greedy = design.greedy_exchange(crit, np.arange(len(A)), 6)
    if kind == "I":
        chosen = design.i_exchange(A, M0, W, chosen, np.arange(len(A)))
    else:
        assert crit.value() == pytest.approx(value(chosen), abs=1e-8)
    assert value(chosen) >= value(greedy) - 1e-12
    best = value(chosen)
    for p in range(len(chosen)):
        for i in set(range(len(A))) - set(chosen):
            trial = list(chosen)
            trial[p] = i
            assert value(trial) <= best + 1e-9 * abs(best)


def test_structural_parameters_are_not_blamed_on_the_pool(cell, tmp_path, invoke):
    """Parameters no poses can identify (structural, e.g. combinations one SMR never tells apart) are not
    called the pool's, nor "left at nominal" when jointcal fit fits them as their share; those a frozen
    wrist takes away are the pool's. (Before: all of them "not identifiable from any poses of this pool
    (left at nominal by jointcal fit)".)"""
    robot, c = cell
    Q = _pool(robot, c, 200, 8)
    Qf = Q.copy()
    Qf[:, 3:] = Qf[0, 3:]
    out = {}
    for name, q in (("full", Q), ("frozen", Qf)):
        _write_pool(tmp_path / f"{name}.csv", q)
        res = invoke("plan", "--robot", KR210, "--spec", SPEC, "--pool", tmp_path / f"{name}.csv", "--n", 20,
                     "--out", tmp_path / f"{name}.plan.csv", "--json", tmp_path / f"{name}.json")
        assert res.exit_code == 0, res.output
        out[name] = (json.loads((tmp_path / f"{name}.json").read_text()), res.stderr)
    full, frozen = out["full"][0], out["frozen"][0]
    structural = set(full["not_identifiable_structural"])
    assert structural and structural == set(full["not_identifiable_on_pool"])     # a broad pool: all structural
    assert set(frozen["not_identifiable_structural"]) == structural                # the same robot, the same
    lost = set(frozen["not_identifiable_on_pool"]) - structural
    assert lost                                                                    # the frozen wrist's
    console = out["frozen"][1]
    pools = [ln for ln in console.splitlines() if "of this pool" in ln]
    assert pools and all(nm in pools[0] for nm in lost) and not any(nm in pools[0] for nm in structural), console
    redundant = [nm for nm, why in full["not_identifiable_on_pool"].items() if why.startswith("redundant")]
    if redundant:
        line = next(ln for ln in out["full"][1].splitlines() if "structural" in ln and "their share" in ln)
        assert all(nm in line for nm in redundant) and "left at nominal" not in line


def test_a_coupled_robots_pool_is_planned_on_the_arms_angles(cell, tmp_path, invoke):
    """With robot.toml's [coupling] (q3 = q2 + q3 of the controller's angles), the pool and the plan are the
    controller's angles and the choice is made on the arm's: the same poses as for the uncoupled robot given
    the combined pool, written as the pool has them."""
    robot, c = cell
    Q = _pool(robot, c, 150, 9)
    rec = Q.copy()
    rec[:, 2] = Q[:, 2] - Q[:, 1]                 # what a FANUC-style controller records for joint 3
    coupled = tmp_path / "coupled.toml"
    coupled.write_text(KR210.read_text() + "\n[coupling]\nq3 = { q2 = 1.0, q3 = 1.0 }\n")
    _write_pool(tmp_path / "arm.csv", Q)
    _write_pool(tmp_path / "rec.csv", rec)
    for name, rob, pool in (("arm", KR210, "arm.csv"), ("rec", coupled, "rec.csv")):
        r = invoke("plan", "--robot", rob, "--spec", SPEC, "--pool", tmp_path / pool, "--n", 15,
                   "--out", tmp_path / f"{name}.plan.csv")
        assert r.exit_code == 0, r.output
    a, b = pd.read_csv(tmp_path / "arm.plan.csv"), pd.read_csv(tmp_path / "rec.plan.csv")
    assert list(a["point_id"]) == list(b["point_id"])
    pool = pd.read_csv(tmp_path / "rec.csv").set_index("point_id")
    cols = [f"q{j}" for j in range(1, 7)]
    assert np.allclose(b[cols].to_numpy(), pool.loc[b["point_id"], cols].to_numpy(), atol=1e-6)
