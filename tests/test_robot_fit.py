"""`jointcal fit --campaign` on a robot campaign: the user adds an effect and watches the held-out error."""

import json

import pytest

from conftest import cli_invoker


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("robotfit")
    out = {}
    for name in ("robot_paper", "robot_beyond"):
        path = tmp / f"{name}.json"
        r = cli_invoker()("fit", "--campaign", "raw/robot/kr210", "--spec", f"specs/{name}.toml", "--out", str(path))
        assert r.exit_code == 0, r.output
        out[name] = json.loads(path.read_text())
    return out


def test_heldout_error_is_on_targets_never_fitted(fits):
    h = fits["robot_paper"]["heldout"]
    assert h["n_sample"] == 100 and h["n_target"] > 0
    # the fitted model must beat the nominal one on poses it never saw
    assert h["after"]["max_mm"] < 0.5 * h["before"]["max_mm"]
    assert h["rms_after_mm"] < h["rms_before_mm"]


def test_adding_the_diagnosed_effect_lowers_heldout_and_cv_error(fits):
    paper, beyond = fits["robot_paper"], fits["robot_beyond"]
    assert "backlash" in beyond["effects"] and "backlash" not in paper["effects"]
    assert beyond["heldout"]["rms_after_mm"] < 0.7 * paper["heldout"]["rms_after_mm"]
    assert beyond["cv_rms_mm"] < 0.7 * paper["cv_rms_mm"]


def test_encoder_spec_on_robot_campaign_is_refused_with_location(tmp_path):
    r = cli_invoker()("fit", "--campaign", "raw/robot/kr210", "--spec", "specs/encoder_paper.toml",
                      "--out", tmp_path / "x.json")
    assert r.exit_code == 2
    assert "specs/encoder_paper.toml:" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "x.json").exists()
