"""A user's own series, timed as a user runs it: ``python -m bench.user_series --source FILE --map MAP
--robot ROBOT [--other CAMPAIGN] [--out JSON]``, or
``make bench-series SERIES=FILE SERIES_MAP=MAP SERIES_ROBOT=ROBOT [SERIES_OTHER=CAMPAIGN]``.

Each step is a fresh ``jointcal`` process, as a user runs it on the command line:

1. ``import`` of the export (the map says how to read it);
2. ``fit`` of geometry + base + tool with an empty wild-point cache (``JOINTCAL_CACHE`` set to a
   new folder: the first fit on these measurements), then once more (the wild points cached);
3. ``predict`` of that fit on the campaign's held-out poses;
4. ``robot diagnose-loop`` from geometry + base + tool to its end (``--other``: another series of the
   same robot, imported, to judge the transfer on), skipped with ``--no-loop``;
5. ``fit`` of the spec the loop ended with (``--spec-out``), and ``predict`` of that model.

For each: wall time (s) and peak resident memory (MB, from ``wait4``: the largest of the process and
the workers it forks and waits for, not their sum), and what it found (held-out RMS, wild points, the loop's rounds). The issue-32 goals on
2 cores: fit <= 5 s, predict <= 2 s (also of the loop's model), diagnose-loop <= 120 s, <= 1 GB each. Nothing is written into the
project; the campaign and the models go to a temporary folder (``--keep DIR`` keeps them).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
JC = str(ROOT / ".venv" / "bin" / "jointcal")
SPEC = ROOT / "specs" / "robot_kinematic.toml"
GOALS = {"fit": (5.0, 1024.0), "fit_cached": (5.0, 1024.0), "predict": (2.0, 1024.0), "diagnose_loop": (120.0, 1024.0),
         "predict_loop_model": (2.0, 1024.0)}


def _run(args, env) -> dict:
    """One command in a fresh process: wall time (s), peak memory (MB), its exit status and stderr's last line."""
    t = time.perf_counter()
    proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    out = {"seconds": round(time.perf_counter() - t, 2), "peak_mb": round(usage.ru_maxrss / 1024.0, 1),
           "exit": proc.returncode}
    if proc.returncode != 0:
        out["error"] = err.strip().splitlines()[-1] if err.strip() else ""
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", required=True, help="the measurement export (one row per pose)")
    ap.add_argument("--map", required=True, help="the import map (docs/formats.md)")
    ap.add_argument("--robot", required=True, help="robot.toml, URDF or calibration.conf (as jointcal import takes)")
    ap.add_argument("--other", help="another imported campaign of the same robot, for the loop's transfer")
    ap.add_argument("--no-loop", action="store_true", help="skip robot diagnose-loop")
    ap.add_argument("--out", help="write the JSON here (default: standard output)")
    ap.add_argument("--keep", help="keep the campaign and the models in this folder")
    a = ap.parse_args(argv)
    work = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="jointcal-series-"))
    work.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               JOINTCAL_CACHE=tempfile.mkdtemp(prefix="wild-", dir=work))
    camp, steps = work / "campaign", {}

    def step(name, args):
        steps[name] = _run([JC] + [str(x) for x in args], env)
        print(f"{name}: {steps[name]['seconds']} s, {steps[name]['peak_mb']} MB", file=sys.stderr)
        return steps[name]["exit"] == 0

    ok = step("import", ["import", "--source", a.source, "--map", a.map, "--robot", a.robot, "--out", camp])
    ok = ok and step("fit", ["fit", "--campaign", camp, "--spec", SPEC, "--out", work / "fit.json"])
    ok = ok and step("fit_cached", ["fit", "--campaign", camp, "--spec", SPEC, "--out", work / "fit2.json"])
    ok = ok and step("predict", ["predict", "--campaign", camp, "--model", work / "fit.json", "--json",
                                 work / "predict.json"])
    if ok and not a.no_loop:
        loop = ["robot", "diagnose-loop", "--campaign", camp, "--spec", SPEC, "--json", work / "loop.json",
                "--spec-out", work / "loop.toml"] + (["--other", a.other] if a.other else [])
        step("diagnose_loop", loop)
        if (work / "loop.toml").exists():
            # what a user does next: the model the loop ended with, fitted and applied (its joint maps make
            # it some hundred parameters, not the kinematic model's few dozen)
            ok = step("fit_loop_model", ["fit", "--campaign", camp, "--spec", work / "loop.toml", "--out",
                                         work / "fit_loop.json"])
            ok = ok and step("predict_loop_model", ["predict", "--campaign", camp, "--model", work / "fit_loop.json",
                                                    "--json", work / "predict_loop.json"])
    doc = {"source": str(a.source), "cpus": len(os.sched_getaffinity(0)), "steps": steps, "goals": {
        k: {"seconds": s, "peak_mb": m, "met": k in steps and steps[k]["exit"] == 0 and steps[k]["seconds"] <= s
            and steps[k]["peak_mb"] <= m} for k, (s, m) in GOALS.items()}}
    if (work / "fit.json").exists():
        fit = json.loads((work / "fit.json").read_text())
        doc["fit"] = {"n_sample": fit["heldout"]["n_sample"], "n_target": fit["heldout"]["n_target"],
                      "heldout_rms_mm": fit["heldout"]["rms_after_mm"], "cv_rms_mm": fit.get("cv_rms_mm"),
                      "wild": [o["point_id"] for o in fit.get("outliers", [])]}
        if "orientation_rms_after_arcsec" in fit["heldout"]:
            doc["fit"]["heldout_orientation_rms_arcsec"] = fit["heldout"]["orientation_rms_after_arcsec"]
    if (work / "loop.json").exists():
        loop = json.loads((work / "loop.json").read_text())
        doc["loop"] = {"done": loop["done"], "rounds": [
            {"round": r["round"], "cv_rms_mm": r.get("cv_rms_mm"), "heldout_rms_mm": r.get("own", {}).get("rms_mm"),
             "other_rms_mm": (r.get("other") or {}).get("rms_mm"),
             "recommended": [x["label"] for x in r.get("recommended", [])]} for r in loop["rounds"]]}
    text = json.dumps(doc, indent=2) + "\n"
    if a.out:
        out = Path(a.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(text)
        tmp.replace(out)
    else:
        sys.stdout.write(text)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
