"""Region splits (issue 52): a campaign's sample poses below a joint's percentile fitted, every pose above
judged. The split is checked against its definition on a small synthetic table and on the shipped KR210
fixture (synthetic: jointcal simulate robot), and the CLI writes a campaign `jointcal fit` reads, or fails
with one line."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, cli_invoker

KR210 = ROOT / "raw" / "robot" / "kr210"


def _poses():
    """Ten sample and five target poses of a 2-joint table; q1 = 0, 10, ... (synthetic)."""
    return pd.DataFrame({"point_id": [f"p{k:02d}" for k in range(16)],
                         "set": ["sample"] * 10 + ["target"] * 5 + ["repeat"],
                         "q1": [10.0 * k for k in range(10)] + [5.0, 15.0, 65.0, 85.0, 95.0, 99.0],
                         "q2": np.linspace(-1, 1, 16)})


def test_the_split_is_below_and_above_the_percentile_of_the_sample_poses():
    from pipeline.robot.campaign.regions import region_split

    split, threshold = region_split(_poses(), 1, 60.0)
    assert threshold == pytest.approx(np.percentile(np.arange(10) * 10.0, 60.0))      # 54
    sets = dict(zip(split.point_id, split.set))
    # sample poses at or below: fitted; every sample or target pose above: judged; targets below, repeats: out
    assert [p for p, s in sets.items() if s == "sample"] == [f"p{k:02d}" for k in range(6)]
    assert [p for p, s in sets.items() if s == "target"] == ["p06", "p07", "p08", "p09", "p12", "p13", "p14"]
    assert not {"p10", "p11", "p15"} & set(sets)
    assert list(split.columns) == ["point_id", "set", "q1", "q2"]
    # by another joint, another split
    other, t2 = region_split(_poses(), 2, 50.0)
    assert t2 == pytest.approx(np.median(np.linspace(-1, 1, 16)[:10]))
    assert (other.loc[other.set == "target", "q2"] > t2).all()
    with pytest.raises(ValueError, match="no joint 3"):
        region_split(_poses(), 3)


def test_the_cli_writes_a_campaign_fit_judges_above_the_split(tmp_path):
    out = tmp_path / "kr210_q2"
    r = cli_invoker()("robot", "region-split", "--campaign", KR210, "--joint", 2, "--out", out)
    assert r.exit_code == 0, r.output
    src = pd.read_csv(KR210 / "poses.csv", dtype={"point_id": str})
    split = pd.read_csv(out / "poses.csv", dtype={"point_id": str})
    limit = np.percentile(src.loc[src.set == "sample", "q2"], 60.0)
    assert (split.loc[split.set == "sample", "q2"] <= limit).all() and (split.loc[split.set == "target", "q2"] > limit).all()
    assert (split.set == "target").sum() == ((src.q2 > limit) & src.set.isin(["sample", "target"])).sum()
    # the rows kept are the campaign's own lines, but for the set
    src_lines = {ln.split(",")[0]: ln for ln in (KR210 / "poses.csv").read_text().splitlines()[1:]}
    for ln in (out / "poses.csv").read_text().splitlines()[1:]:
        f, g = ln.split(","), src_lines[ln.split(",")[0]].split(",")
        assert f[:1] + f[2:] == g[:1] + g[2:]
    tracker_ids = pd.read_csv(out / "tracker.csv", dtype={"point_id": str}).point_id
    assert sorted(tracker_ids) == sorted(split.point_id)
    fit = tmp_path / "fit.json"
    r = cli_invoker()("fit", "--campaign", out, "--spec", ROOT / "specs" / "robot_kinematic.toml", "--out", fit)
    assert r.exit_code == 0, r.output
    h = json.loads(fit.read_text())["heldout"]
    assert h["n_target"] + len(json.loads(fit.read_text())["outliers"]) >= (split.set == "target").sum() - 5
    assert json.loads(fit.read_text())["sampled_range"]["upper_deg"][1] <= limit + 1e-9


@pytest.mark.parametrize("campaign, joint, says", [(KR210, 9, "no joint 9"), (KR210 / "nowhere", 1, "not found")])
def test_a_bad_split_is_one_line_and_writes_nothing(tmp_path, campaign, joint, says):
    out = tmp_path / "x"
    r = cli_invoker()("robot", "region-split", "--campaign", campaign, "--joint", joint, "--out", out)
    assert r.exit_code == 2 and says in r.output, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("jointcal: error:") and "Traceback" not in r.output
    assert not out.exists() and not list(tmp_path.iterdir())
