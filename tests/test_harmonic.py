"""Harmonic analysis (paper 1, Eqs. 1-4): exactness, LSQ vs FFT, aliasing."""

import numpy as np
import pytest

from pipeline.encoder.aliasing import OrderTooHighError, alias_table, check_orders, fold
from pipeline.encoder.harmonic import amplitude_phase, fft_coefficients, lsq_coefficients


def signal(theta_deg, terms, c0=0.0):
    th = np.deg2rad(theta_deg)
    return c0 + sum(C * np.sin(i * th + np.deg2rad(phi)) for i, (C, phi) in terms.items())


TERMS = {1: (14.1, 243.75), 4: (6.91, 26.73), 8: (18.05, 46.5), 14: (33.36, 20.82), 17: (2.5, 300.0)}


@pytest.mark.parametrize("uneven", [False, True])
def test_lsq_recovers_amplitude_and_phase_exactly(uneven):
    rng = np.random.default_rng(1)
    theta = np.arange(37) * 10.0
    if uneven:
        theta = np.sort(rng.uniform(0, 360, 61))
    y = signal(theta, TERMS, c0=-11.47)
    orders = list(range(18))
    A, B = lsq_coefficients(theta, y, orders)
    C, phi = amplitude_phase(A, B)
    assert A[0] == pytest.approx(-11.47, abs=1e-9)
    for i in range(1, 18):
        want_C, want_phi = TERMS.get(i, (0.0, None))
        assert C[i] == pytest.approx(want_C, abs=1e-9)
        if want_phi is not None:
            assert phi[i] == pytest.approx(want_phi, abs=1e-9)


def test_lsq_and_fft_agree_on_even_angles():
    rng = np.random.default_rng(2)
    theta0 = 3.7
    theta = theta0 + np.arange(36) * 10.0
    y = signal(theta, TERMS, 1.0) + rng.normal(0, 2.0, theta.size)  # noise too: the two must still agree
    A, B = lsq_coefficients(theta, y, range(18))
    Af, Bf = fft_coefficients(y, 17, theta0_deg=theta0)
    np.testing.assert_allclose(Af, A, atol=1e-9)
    np.testing.assert_allclose(Bf, B, atol=1e-9)


def test_order_22_at_36_angles_lands_on_order_14_as_eq3_says():
    theta = np.arange(36) * 10.0
    A22, B22 = 3.0, 5.0
    th = np.deg2rad(theta)
    y = A22 * np.cos(22 * th) + B22 * np.sin(22 * th)
    A, B = lsq_coefficients(theta, y, range(18))
    # Eq. 3 with N = 36, i = 14, k = 1: a_14 = A_14 + A_(36-14) ;  b_14 = B_14 - B_(36-14)
    assert A[14] == pytest.approx(A22, abs=1e-9)
    assert B[14] == pytest.approx(-B22, abs=1e-9)
    others = np.delete(np.hypot(A, B), 14)
    assert np.all(others < 1e-9)
    assert fold(22, 36) == (14, -1)
    assert fold(50, 36) == (14, +1)


def test_alias_table_lists_eq4_sources():
    rows = {r["order"]: r for r in alias_table(37, 18, highest=80)}
    # the paper's Eq. 4 for N = 37: a_1 = A1 + A36 + A38 + A73 ...; a_17 = A17 + A20 + A54 + A57
    assert rows[1]["cos_from"][:3] == [36, 38, 73]
    assert rows[1]["cos_from"] == [36, 38, 73, 75]
    assert rows[17]["cos_from"] == [20, 54, 57]          # 91 is above highest = 80
    assert 19 in rows[18]["sin_minus"] and 55 in rows[18]["sin_plus"]


def test_orders_above_nyquist_are_refused():
    check_orders([18], 36)
    with pytest.raises(OrderTooHighError, match="N/2 = 18"):
        check_orders([19], 36)


def test_nyquist_order_has_no_sine_sources():
    rows = {r["order"]: r for r in alias_table(36, 18, highest=100)}
    assert rows[18]["sin_plus"] == [] and rows[18]["sin_minus"] == []
    assert rows[18]["cos_from"][:2] == [54, 90]
    assert "not estimable" in rows[18]["equation"]
    assert rows[0]["sin_plus"] == [] and rows[0]["cos_from"][:2] == [36, 72]


def test_alias_frame_is_the_table_for_every_resolvable_order():
    """alias_frame, the library of `jointcal aliasing`: N = 36 resolves orders 0..18; order 1 gathers
    35, 37, 71, 73 in its cosine, 37 and 73 added to its sine, 35 and 71 subtracted (Eq. 4)."""
    from pipeline.encoder.aliasing import alias_frame

    t = alias_frame(36, highest=80)
    assert list(t.columns) == ["N_distinct", "order", "folds_from", "sin_added", "sin_subtracted", "equation"]
    assert list(t["order"]) == list(range(19)) and set(t["N_distinct"]) == {36}
    one = t.set_index("order").loc[1]
    assert one["folds_from"] == "35 37 71 73"
    assert one["sin_added"] == "37 73" and one["sin_subtracted"] == "35 71"
    assert t.set_index("order").loc[18, "sin_added"] == ""          # the sine of N/2 vanishes at every sample


def test_selection_document_uses_the_specs_explicit_orders(tmp_path):
    """selection_document, the library of `jointcal select`, on the shipped synthetic module a: the
    paper rule's and the cross-validated orders beside the ones used, the spec's own when it names them."""
    from conftest import ROOT

    from pipeline.core.spec import parse_spec
    from pipeline.encoder.harmonic import analyse_runs
    from pipeline.encoder.ingest import ingest_encoder
    from pipeline.encoder.selection import selection_document

    frame = ingest_encoder(ROOT / "raw" / "encoder" / "a")
    text = (ROOT / "specs" / "encoder_paper.toml").read_text()
    spec = parse_spec(text, "paper.toml")
    harmonics = analyse_runs(frame)
    doc = selection_document(frame, spec, harmonics)
    assert doc["orders"] == doc["paper_rule_orders"] and doc["rule"] == spec.select.get("rule", "paper")
    assert doc["cv_path"][0]["added"] is None
    assert sorted(p["added"] for p in doc["cv_path"][1:]) == sorted(doc["cv_orders"])
    assert 1 in doc["orders"] and doc["module"] == str(frame["module"].iloc[0])
    own = selection_document(frame, parse_spec(text.replace('name = "harmonic"\n', 'name = "harmonic"\norders = [4, 1]\n'),
                                               "own.toml"), harmonics)
    assert own["orders"] == [1, 4] and own["rule"] == "spec" and own["paper_rule_orders"] == doc["paper_rule_orders"]
