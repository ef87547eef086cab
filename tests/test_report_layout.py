"""Every report page laid out for a reader (issue 54): rendered page by page, each fails when a text falls
outside its page, a legend is empty (or matplotlib finds nothing to label), a page outside the appendix
holds more than a few lines of monospaced text, or the first page is not a table of the headline numbers
with a picture.

The reports are built through the library functions ``make all`` and ``jointcal`` use, on the shipped
fixtures (encoder, robot, diagnosis, a small simulated fleet) and on a campaign the project does not
ship: a simulated 7-joint arm (the Panda of raw/arms), fitted and predicted like a user's robot.
"""

from __future__ import annotations

import json
import warnings

import pytest
from matplotlib.backends.backend_pdf import PdfPages
import matplotlib.text as mtext

from conftest import ROOT, cli_invoker

#: characters of monospaced text a page outside the appendix may hold (a short aligned note; a console
#: dump of a table or a log is many times more)
MAX_MONOSPACE_CHARS = 300
#: pixels a text may reach past the page's edge (anti-aliasing)
TOLERANCE_PX = 1.0
#: pixels two texts may share both ways (glyph boxes include their line spacing) before they overlap
OVERLAP_PX = 2.0
APPENDIX = "Appendix"


def _drawn_texts(fig):
    """The texts drawing the figure actually draws (not the stale tick labels of ticks it skips)."""
    seen = []
    original = mtext.Text.draw

    def draw(self, renderer):
        original(self, renderer)
        if self.get_visible() and self.get_text().strip():
            seen.append(self)

    mtext.Text.draw = draw
    try:
        fig.canvas.draw()
    finally:
        mtext.Text.draw = original
    return seen


def _is_mono(t):
    return any("mono" in f.lower() for f in t.get_fontfamily())


def page_problems(fig) -> tuple[list[str], dict]:
    """What is wrong with one page (an empty list when nothing), and what it holds."""
    texts = _drawn_texts(fig)
    renderer = fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    problems = []
    for t in texts:
        bb = t.get_window_extent(renderer)
        if bb.x0 < -TOLERANCE_PX or bb.y0 < -TOLERANCE_PX or bb.x1 > W + TOLERANCE_PX or bb.y1 > H + TOLERANCE_PX:
            problems.append(f"text outside the page ({bb.x0:.0f}..{bb.x1:.0f} of {W:.0f} px wide, "
                            f"{bb.y0:.0f}..{bb.y1:.0f} of {H:.0f} px high): {t.get_text()[:60]!r}")
    boxes = [(t, t.get_window_extent(renderer)) for t in texts]
    for i, (a, ba) in enumerate(boxes):
        for b, bb in boxes[i + 1:]:
            w = min(ba.x1, bb.x1) - max(ba.x0, bb.x0)
            h = min(ba.y1, bb.y1) - max(ba.y0, bb.y0)
            if w > OVERLAP_PX and h > OVERLAP_PX:
                problems.append(f"{a.get_text()[:40]!r} overlaps {b.get_text()[:40]!r} ({w:.0f} x {h:.0f} px)")
    legends = [ax.get_legend() for ax in fig.axes] + list(fig.legends)
    for leg in legends:
        if leg is not None and not [t for t in leg.get_texts() if t.get_text().strip()]:
            problems.append("an empty legend")
    appendix = any(t.get_text().startswith(APPENDIX) for t in texts)
    mono = sum(len(t.get_text().replace(" ", "")) for t in texts if _is_mono(t))
    if not appendix and mono > MAX_MONOSPACE_CHARS:
        problems.append(f"{mono} characters of monospaced text outside the appendix")
    tables = [ax for ax in fig.axes if ax.get_visible() and not ax.axison
              and sum(1 for t in texts if t.axes is ax) >= 6]
    pictures = [ax for ax in fig.axes if ax.get_visible() and ax.axison
                and (ax.lines or ax.patches or ax.collections or ax.images)]
    return problems, {"appendix": appendix, "table": bool(tables), "picture": bool(pictures), "mono": mono,
                      "text": "\n".join(t.get_text() for t in texts)}


class Recorder:
    """Checks every page a report writes (PdfPages.savefig patched), by output file."""

    def __init__(self):
        self.pages = {}

    def __call__(self, original):
        rec = self

        def savefig(self, figure=None, **kw):
            fig = figure if figure is not None else __import__("matplotlib.pyplot").pyplot.gcf()
            name = getattr(self, "_jointcal_name", None) or str(id(self))
            rec.pages.setdefault(name, []).append(page_problems(fig))
            return original(self, figure, **kw)

        return savefig


@pytest.fixture
def recorder(monkeypatch):
    rec = Recorder()
    monkeypatch.setattr(PdfPages, "savefig", rec(PdfPages.savefig))
    return rec


def check_report(rec, write):
    """Run ``write()`` (one report), failing on matplotlib's "no artists with labels" warning; then every
    page's problems, the first page's table and picture, and the appendix last."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        write()
    labels = [str(w.message) for w in caught if "No artists with labels" in str(w.message)]
    assert not labels, labels
    assert len(rec.pages) == 1, list(rec.pages)
    pages = next(iter(rec.pages.values()))
    rec.pages.clear()
    bad = [f"page {k + 1}: {p}" for k, (problems, _) in enumerate(pages) for p in problems]
    assert not bad, "\n".join(bad)
    first = pages[0][1]
    assert first["table"] and first["picture"] and not first["appendix"] and first["mono"] == 0, first
    kinds = [info["appendix"] for _, info in pages]
    assert kinds == sorted(kinds), "an appendix page before a page of figures"
    return pages


# ---------------------------------------------------------------------------------------------- checks
def test_the_checks_fail_on_a_bad_page():
    """The checker itself: a title past the edge, an empty legend and a console dump are each found."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0, 1], [0, 1])
    ax.set_title("a title far too long for a figure four inches wide, running off both of its edges")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ax.legend()
    fig.text(0.0, 0.5, "\n".join(["x = 1.000   y = 2.000   z = 3.000"] * 20), family="monospace", fontsize=4)
    fig.text(0.5, 0.5, "one text", fontsize=9)
    fig.text(0.52, 0.5, "over another", fontsize=9)
    problems, info = page_problems(fig)
    plt.close(fig)
    assert any("outside the page" in p for p in problems)
    assert "an empty legend" in problems
    assert any("monospaced" in p for p in problems)
    assert any("overlaps" in p and "one text" in p for p in problems)
    assert info["picture"] and not info["table"]


# ---------------------------------------------------------------------------------------------- encoder
def test_encoder_report_layout(recorder, tmp_path):
    from test_encoder_cli import run_chain
    from pipeline.core.files import read_parquet
    from pipeline.encoder.report import encoder_report

    invoke = cli_invoker()
    inputs = {}
    for m in "ab":
        work = run_chain(invoke, ROOT / "raw" / "encoder" / m, tmp_path / m)
        inputs[m] = {"readings": read_parquet(work / "m.parquet"), "harmonics": read_parquet(work / "h.parquet"),
                     "selection": json.loads((work / "orders.json").read_text()),
                     "model": json.loads((work / "model.json").read_text()), "aliasing": work / "alias.csv"}
    pages = check_report(recorder, lambda: encoder_report(inputs, tmp_path / "encoder.pdf"))
    assert sum(info["appendix"] for _, info in pages) >= 3     # numbers, terms, aliasing: console text, last
    # the first page's numbers are the ones README quotes, as it quotes them (docs/quoted-numbers.toml: .2f)
    first = pages[0][1]["text"].split("\n")
    for m in "ab":
        model = inputs[m]["model"]
        for key in ("p2p_before_arcsec", "p2p_after_arcsec", "reduction_pct"):
            assert f"{model[key]:.2f}" in first, (m, key)


# ---------------------------------------------------------------------------------------------- diagnosis
def test_diagnosis_report_layout(recorder, tmp_path):
    """make all's diagnosis.pdf: the encoder modules and the robot campaign, each with its spec."""
    from pipeline.diagnosis.campaign import run_diagnosis
    from pipeline.diagnosis.report import diagnosis_report_many

    pairs = [(ROOT / "raw" / "encoder" / "a", ROOT / "specs" / "encoder_paper.toml"),
             (ROOT / "raw" / "robot" / "kr210", ROOT / "specs" / "robot_paper.toml")]
    items = [run_diagnosis(c, s) for c, s in pairs]
    check_report(recorder, lambda: diagnosis_report_many([(r, *rest) for r, rest in items], tmp_path / "d.pdf",
                                                         names=[str(c.relative_to(ROOT)) for c, _ in pairs]))


# ---------------------------------------------------------------------------------------------- robot paper
def test_robot_report_layout(recorder, tmp_path):
    from test_robot_end_to_end import run_chain
    from pipeline.robot.reporting.report import robot_report

    run_chain(tmp_path)
    common = ["--interim", tmp_path / "poses.parquet", "--robot", ROOT / "raw/robot/kr210/robot.toml"]
    r = cli_invoker()("robot", "closed-loop", *common, "--corrected", tmp_path / "corrected_targets.csv",
                      "--out", tmp_path / "closed_loop.json")
    assert r.exit_code == 0, r.output
    read = lambda name: json.loads((tmp_path / name).read_text())  # noqa: E731
    inputs = {"table2": read("table2.json"), "mdh": read("mdh.json"), "chebyshev": read("chebyshev.json"),
              "closed_loop": read("closed_loop.json"),
              "iso": read("iso9283.json") if (tmp_path / "iso9283.json").exists() else {},
              "errors": tmp_path / "target_errors.csv", "repeat": tmp_path / "repeat_positions.csv",
              "beyond": {"table2": read("table2.json"), "diagnosis": None}}
    check_report(recorder, lambda: robot_report(inputs, tmp_path / "robot.pdf"))


# ---------------------------------------------------------------------------------------------- fleet
def test_fleet_report_layout(recorder, tmp_path):
    invoke = cli_invoker()
    r = invoke("simulate", "fleet", "--out", tmp_path / "raw", "--truth", tmp_path / "truth", "--units", 8,
               "--seed", 11)
    assert r.exit_code == 0, r.output
    pages = check_report(recorder, lambda: invoke(
        "fleet", "--campaigns", f"{tmp_path}/raw/*", "--spec", ROOT / "specs" / "encoder_paper.toml", "--out-dir",
        tmp_path / "res", "--table", tmp_path / "fleet.parquet", "--report", tmp_path / "fleet.pdf", "--serial"))
    # no page repeats another's picture (page 3 drew page 1's before / after again)
    shown = [info["text"].count("Every unit: before and after") for _, info in pages]
    assert sum(shown) == 1, shown


# ---------------------------------------------------------------------------------------------- any robot
@pytest.fixture(scope="module")
def seven_joint_arm(tmp_path_factory):
    """Two simulated campaigns of a 7-joint arm (the Panda), each fitted with geometry + base + tool and
    with the backlash the cell hides, and predicted on its own held-out poses and on the other (registered):
    a robot the project ships no measurements of."""
    from test_any_arm import KINEMATIC, PANDA, _clean_campaign

    tmp = tmp_path_factory.mktemp("panda")
    invoke = cli_invoker()
    hidden = {"effect": "backlash", "joint": 2, "arcsec": 100.0}
    for name, seed in (("east", 2), ("west", 3)):
        _clean_campaign(tmp / "campaigns" / name, PANDA, hidden, seed=seed)
    spec = tmp / "backlash.toml"
    spec.write_text(KINEMATIC.read_text() + '\n[[effect]]\nname = "backlash"\njoints = [2]\n')
    res = tmp / "results"
    for name, other in (("east", "west"), ("west", "east")):
        camp = tmp / "campaigns" / name
        for model, sp in (("kinematic", KINEMATIC), ("backlash", spec)):
            fit = res / f"{name}_{model}.json"
            r = invoke("fit", "--campaign", camp, "--spec", sp, "--out", fit)
            assert r.exit_code == 0, r.output
            r = invoke("predict", "--campaign", camp, "--model", fit, "--json", res / f"{name}_{model}_self.json")
            assert r.exit_code == 0, r.output
            r = invoke("predict", "--campaign", tmp / "campaigns" / other, "--model", fit, "--register",
                       "--json", res / f"{name}_{model}_on_{other}.json")
            assert r.exit_code == 0, r.output
    return tmp


def test_real_report_of_a_users_seven_joint_arm(recorder, seven_joint_arm):
    """`jointcal robot real-report` from the user's own fit and predict JSONs: laid out, no UR10 text."""
    tmp = seven_joint_arm
    res = tmp / "results"
    out = tmp / "mine.pdf"
    args = ["robot", "real-report", "--campaign", tmp / "campaigns" / "east", "--out", out, "--other-name", "west"]
    for model in ("kinematic", "backlash"):
        args += ["--fit", res / f"east_{model}.json", "--predict", res / f"east_{model}_self.json",
                 "--other", res / f"east_{model}_on_west.json"]
    result = {}

    def write():
        result["r"] = cli_invoker()(*args)

    pages = check_report(recorder, write)
    assert result["r"].exit_code == 0, result["r"].output
    assert out.exists() and "backlash" in result["r"].output and "kinematic" in result["r"].output
    text = "\n".join(info["text"] for _, info in pages)
    assert "east" in text and "backlash" in text
    for ur10 in ("UR10", "T-Mac", "0.45-0.48", "README", "0.006 deg", "300 mm"):
        assert ur10 not in text, ur10


def test_real_report_of_two_series_by_makes_names(recorder, seven_joint_arm, tmp_path):
    """make real's report (every series by make's file names, the other series registered), on the arm."""
    from pipeline.robot.reporting.real_report import load_campaigns, load_results, real_report

    tmp = seven_joint_arm
    campaigns = load_campaigns(tmp / "campaigns")
    results = load_results(tmp / "results", list(campaigns))
    # load_results reads make's models (kinematic, paper, diagnosed): the arm's backlash fit as "diagnosed"
    for s in campaigns:
        r = results[s]
        o = "west" if s == "east" else "east"
        r["fits"]["diagnosed"] = json.loads((tmp / "results" / f"{s}_backlash.json").read_text())
        r["self"]["diagnosed"] = json.loads((tmp / "results" / f"{s}_backlash_self.json").read_text())
        r["on"]["diagnosed"] = {o: json.loads((tmp / "results" / f"{s}_backlash_on_{o}.json").read_text())}
    pages = check_report(recorder, lambda: real_report(results, campaigns, tmp_path / "real.pdf"))
    # the first page's numbers: the fits' held-out RMS before / after as README quotes them (.3f)
    first = pages[0][1]["text"].split("\n")
    for s in campaigns:
        h = results[s]["fits"]["kinematic"]["heldout"]
        assert f"{h['rms_before_mm']:.3f}" in first and f"{h['rms_after_mm']:.3f}" in first, s


def test_real_report_shows_the_series_together_and_the_region_splits(recorder, seven_joint_arm, tmp_path):
    """Issue 52: make real's report with the series fitted together (make's <series...>_together.json and its
    _self predict) and a region split of one series (<series>_split_q<j>.json and _above.json): a page beside
    the summary states each, from those files' numbers, and draws where the models fail (synthetic arm)."""
    import shutil

    from pipeline.robot.reporting.real_report import load_campaigns, load_results, real_report

    tmp, res = seven_joint_arm, tmp_path / "results"
    shutil.copytree(seven_joint_arm / "results", res)
    invoke = cli_invoker()
    camps = [tmp / "campaigns" / "east", tmp / "campaigns" / "west"]
    for s in ("east", "west"):       # make's "diagnosed": the arm's backlash fit
        for suffix in ("", "_self", "_on_" + ("west" if s == "east" else "east")):
            shutil.copy(res / f"{s}_backlash{suffix}.json", res / f"{s}_diagnosed{suffix}.json")
    spec = tmp_path / "backlash.toml"
    spec.write_text((ROOT / "specs" / "robot_kinematic.toml").read_text()
                    + '\n[[effect]]\nname = "backlash"\njoints = [2]\n')
    r = invoke("fit", "--campaign", camps[0], "--campaign", camps[1], "--spec", spec, "--out", res / "eastwest_together.json")
    assert r.exit_code == 0, r.output
    r = invoke("predict", "--campaign", camps[0], "--campaign", camps[1], "--model", res / "eastwest_together.json",
               "--json", res / "eastwest_together_self.json")
    assert r.exit_code == 0, r.output
    r = invoke("robot", "region-split", "--campaign", camps[0], "--joint", 2, "--out", tmp_path / "east_q2")
    assert r.exit_code == 0, r.output
    r = invoke("fit", "--campaign", tmp_path / "east_q2", "--spec", spec, "--out", res / "east_split_q2.json")
    assert r.exit_code == 0, r.output
    r = invoke("predict", "--campaign", tmp_path / "east_q2", "--model", res / "east_split_q2.json",
               "--json", res / "east_split_q2_above.json")
    assert r.exit_code == 0, r.output
    campaigns = load_campaigns(tmp / "campaigns")
    results = load_results(res, list(campaigns))
    table = {}
    pages = check_report(recorder, lambda: table.update(real_report(results, campaigns, tmp_path / "real.pdf")))
    where = [info for _, info in pages if "Where the models hold" in info["text"]]
    assert len(where) == 1 and where[0]["table"] and where[0]["picture"]
    text = where[0]["text"]
    together = json.loads((res / "eastwest_together.json").read_text())
    for c in together["campaigns"]:
        assert f"{c['heldout']['rms_after_mm']:.3f}" in text, c["campaign"]
    split = json.loads((res / "east_split_q2.json").read_text())["heldout"]
    above = json.loads((res / "east_split_q2_above.json").read_text())
    assert f"{split['rms_after_mm']:.3f}" in text and f"{100 * above['coverage_95']:.1f}" in text
    assert table["east"]["splits"][0]["n"] == split["n_target"] and table["west"]["together"]["with"] == ["east", "west"]


def test_real_report_without_campaign_takes_the_fits_or_says_in_one_line(seven_joint_arm, tmp_path):
    """Issue 53: `robot real-report --fit F` without --campaign printed click's three-line usage error; it
    takes the campaign the fit names, and when that is not there says so in one line (exit 2)."""
    res = seven_joint_arm / "results"
    ok = cli_invoker()("robot", "real-report", "--fit", res / "east_kinematic.json", "--predict",
                       res / "east_kinematic_self.json", "--out", tmp_path / "a.pdf")
    assert ok.exit_code == 0, ok.output
    doc = json.loads((res / "east_kinematic.json").read_text())
    doc["campaign"] = str(tmp_path / "moved")
    (tmp_path / "fit.json").write_text(json.dumps(doc))
    r = cli_invoker()("robot", "real-report", "--fit", tmp_path / "fit.json", "--predict",
                      res / "east_kinematic_self.json", "--out", tmp_path / "b.pdf")
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2 and len(lines) == 1, r.output
    assert lines[0].startswith(f"jointcal: error: {tmp_path / 'fit.json'}:") and "--campaign" in lines[0]
    assert not (tmp_path / "b.pdf").exists()


def test_diagnosis_report_of_a_users_seven_joint_arm(recorder, seven_joint_arm, tmp_path):
    """`jointcal diagnose --report` on the arm's campaign (a folder name the project never uses): laid out."""
    from test_any_arm import KINEMATIC

    result = {}

    def write():
        result["r"] = cli_invoker()("diagnose", "--campaign", seven_joint_arm / "campaigns" / "east", "--spec", KINEMATIC,
                                    "--json", tmp_path / "d.json", "--report", tmp_path / "d.pdf", "--quiet")

    pages = check_report(recorder, write)
    assert result["r"].exit_code == 0, result["r"].output
    assert "backlash joint 2" in pages[0][1]["text"]      # the hidden effect, named on the first page


def test_a_long_title_keeps_two_lines_its_start_and_its_end():
    """An appendix title naming a deep folder (a user's campaign) is cut in its middle, not wrapped onto
    the text below it; a title that fits two lines is left as it is."""
    from pipeline.core.plotting import fit_lines, fit_text

    long = "Appendix 1: Diagnosis of " + "/very/deep" * 20 + "/campaigns/east: candidates, evidence"
    out = fit_lines(long, 7.3, 12)
    assert out.count("\n") == 1 and "..." in out
    assert out.startswith("Appendix 1: Diagnosis of /very") and out.endswith("candidates, evidence")
    short = "Appendix 3: Diagnosis of raw/robot/kr210: candidates, evidence, what cannot be revealed"
    assert fit_lines(short, 7.3, 12) == fit_text(short, 7.3, 12)


def test_a_title_centred_over_a_narrow_axes_is_wrapped_onto_the_page():
    """An axes pushed right by long tick labels: its long title, centred over it, reached past the page's
    right edge; title_on_page wraps it to fit there and leaves a title that fits as it is."""
    from pipeline.core.plotting import fit_text, plt, title_on_page

    fig, ax = plt.subplots(figsize=(8.27, 5))
    ax.barh([0, 1], [1, 2])
    ax.set_yticks([0, 1])
    ax.set_yticklabels(["a very long candidate label of an effect", "another long one"])
    head = "a campaign folder: cross-validated gain of adding each candidate effect (the first 30 of 135; every one)"
    ax.set_title(fit_text(head, 0.85 * 8.27, 10), fontsize=10)
    fig.tight_layout()
    r = fig.canvas.get_renderer()
    assert ax.title.get_window_extent(r).x1 > fig.bbox.width          # the fault, as drawn before
    title_on_page(fig, ax, head, 10)
    box = ax.title.get_window_extent(r)
    assert 0 <= box.x0 and box.x1 <= fig.bbox.width
    before = ax.title.get_text()
    title_on_page(fig, ax, head, 10)
    assert ax.title.get_text() == before
    plt.close(fig)
