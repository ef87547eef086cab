"""The encoder effect ``polygon`` (contract section 3), the worked example of docs/adding-an-effect.md:
the polygon's own face errors, separable from the joint's error when runs start on different faces."""

import numpy as np
import pandas as pd

from pipeline.core.spec import Spec
from pipeline.diagnosis.encoder import EncoderAdapter
from pipeline.diagnosis.engine import diagnose
from pipeline.encoder.effects import EncoderData, Harmonic, Polygon
from pipeline.encoder.evaluate import cross_validate
from pipeline.encoder.ingest import derive_encoder
from pipeline.encoder.model import EncoderModel
from pipeline.encoder.simulate import PAPER_MODELS, clean_encoder_config, simulate_encoder

NOISE = 0.9
FACES = 36


def face_errors(seed, rms=3.0):
    """A few arcsec per face, summing to zero (a polygon's certificate)."""
    f = np.random.default_rng(seed).normal(0.0, rms, FACES)
    return f - f.mean()


def campaign(seed, settings, f, certificate=None):
    cfg = clean_encoder_config("a", seed, NOISE)
    hidden = {"effect": "polygon", "face_error_arcsec": [float(v) for v in f], "settings": settings}
    frame, _ = simulate_encoder("a", cfg, runs=6, hidden=hidden)
    frame["_file"], frame["_line"] = "sim.csv", 0
    frame["timestamp"] = pd.to_datetime(frame["timestamp"])
    campaign = {"faces": FACES} if certificate is None else {"faces": FACES, "face_error_arcsec": list(certificate)}
    return EncoderData.from_frame(derive_encoder(frame, campaign))


def joint_spec(extra=()):
    return Spec("encoder", [Harmonic(orders=sorted(PAPER_MODELS["a"])), *extra], {"fit": "pooled"}, {})


def test_face_errors_with_three_settings_are_named_first_and_the_joint_error_recovered():
    f = face_errors(5)
    data = campaign(21, [0, 13, 26], f)
    result = diagnose(EncoderAdapter(), joint_spec(), data)
    top = result["candidates"][0]
    assert (top["effect"], top["target"]) == ("polygon", None), [(c["effect"], c["target"], round(c["gain"], 3)) for c in result["candidates"][:4]]
    assert top["meaningful"]
    assert "polygon face" in top["evidence"]
    baseline = result["baseline"]["cv_rms"]
    assert baseline > 2 * NOISE                       # the face errors are plainly there without the effect
    assert top["cv_rms_with"] <= 1.2 * NOISE          # with it: down to the reading noise
    # once in the spec: the joint's own error (the paper's terms) and the face errors are recovered
    model = EncoderModel(joint_spec([Polygon()]).effects).fit(data)
    fitted = Polygon.face_errors([model.coef_[model.labels_.index(f"face_error_arcsec_{k}")] for k in range(FACES - 1)])
    # each face is read about 6 times (once a run): its error is known to about NOISE / sqrt(6)
    assert np.sqrt(np.mean((fitted - f) ** 2)) < 1.5 * NOISE / np.sqrt(6)
    for t in model.terms():
        C, phi = PAPER_MODELS["a"][t["order"]]
        assert abs(t["C_arcsec"] - C) < 0.5 * NOISE, t
    assert cross_validate(joint_spec([Polygon()]).effects, data).rms <= 1.2 * NOISE


def test_one_setting_cannot_reveal_it():
    data = campaign(22, [7], face_errors(6))
    ok, why = Polygon().can_reveal(data)
    assert not ok and "same face" in why
    result = diagnose(EncoderAdapter(), joint_spec(), data)
    assert [u["reason"] for u in result["not_revealable"] if u["effect"] == "polygon"] == [why]
    assert all(c["effect"] != "polygon" for c in result["candidates"])


def test_a_certificate_removes_the_face_errors_before_the_model_sees_them():
    f = face_errors(7)
    data = campaign(23, [0, 13, 26], f, certificate=f)
    result = diagnose(EncoderAdapter(), joint_spec(), data)
    assert result["baseline"]["cv_rms"] <= 1.2 * NOISE
    assert not [c for c in result["candidates"] if c["meaningful"]]


def test_settings_that_repeat_the_polygon_leave_some_face_errors_undetermined():
    """Settings 0, 12, 24 of 36 faces see face-error orders 3, 6, ... alike: the fit still
    predicts (CV at the noise) but cannot tell those components from the joint's orders 12, 15."""
    f = face_errors(9)
    data = campaign(25, [0, 12, 24], f)
    assert cross_validate(joint_spec([Polygon()]).effects, data).rms <= 1.2 * NOISE
    model = EncoderModel(joint_spec([Polygon()]).effects).fit(data)
    fitted = Polygon.face_errors([model.coef_[model.labels_.index(f"face_error_arcsec_{k}")] for k in range(FACES - 1)])
    assert np.sqrt(np.mean((fitted - f) ** 2)) > 2 * NOISE


def test_simulator_settings_separate_every_face_error_order():
    from pipeline.encoder.effects import spread_settings
    from pipeline.encoder.simulate import hidden_encoder_effect

    assert spread_settings(3, 36) == [0, 13, 26] and spread_settings(2, 36) == [0, 19]
    hid = hidden_encoder_effect("polygon", 1)
    assert hid["settings"] == [0, 13, 26] and len(hid["face_error_arcsec"]) == FACES
    assert abs(sum(hid["face_error_arcsec"])) < 0.01


def test_columns_give_face_errors_that_sum_to_zero():
    data = campaign(24, [0, 13, 26], face_errors(8))
    labels, X = Polygon().columns(data)
    assert len(labels) == X.shape[1] == FACES - 1
    coef = np.arange(FACES - 1, dtype=float)
    full = Polygon.face_errors(coef)
    assert abs(full.sum()) < 1e-12
    np.testing.assert_allclose(X @ coef, full[data.face])   # an uncertified face error stays in error_arcsec as +f_face


def test_simulate_cli_hides_face_errors_and_diagnose_names_them(invoke, tmp_path):
    """`jointcal simulate encoder --hidden polygon` (the fixture's physics, three settings) and
    `jointcal diagnose` with the paper's spec: polygon is the first candidate; --help lists it."""
    import json

    from conftest import ROOT

    assert "polygon[:SETTINGS]" in invoke("simulate", "encoder", "--help").output
    res = invoke("simulate", "encoder", "--out", tmp_path / "sim", "--truth", tmp_path / "truth", "--module", "a",
                 "--hidden", "polygon")
    assert res.exit_code == 0, res.output
    runs = pd.read_csv(tmp_path / "sim" / "a" / "a_run2.csv")
    assert runs["setting"].unique().tolist() == [13]
    res = invoke("diagnose", "--campaign", tmp_path / "sim" / "a", "--spec", ROOT / "specs" / "encoder_paper.toml",
                 "--json", tmp_path / "d.json", "--quiet")
    assert res.exit_code == 0, res.output
    top = json.loads((tmp_path / "d.json").read_text())["candidates"][0]
    assert top["effect"] == "polygon" and top["meaningful"], top


def test_polygon_is_not_in_the_compensation_table():
    data = campaign(26, [0, 13, 26], face_errors(10))
    with_polygon = EncoderModel(joint_spec([Polygon()]).effects).fit(data)
    assert not Polygon.compensable and Harmonic.compensable
    theta = np.arange(0.0, 360.0, 0.5)
    harmonic_only = EncoderModel([Harmonic(orders=with_polygon.orders_)])
    harmonic_only.orders_, harmonic_only.C0_ = with_polygon.orders_, with_polygon.C0_
    n = 2 * len([o for o in with_polygon.orders_ if o])
    harmonic_only.labels_, harmonic_only.coef_ = with_polygon.labels_[:n], with_polygon.coef_[:n]
    np.testing.assert_array_equal(with_polygon.predict_theta(theta), harmonic_only.predict_theta(theta))
