"""At a user's scale (issue 32): ``run() -> dict``.

A simulated UR10 campaign (:mod:`bench.ur10_scale`: the kind of errors the real series show, 6 wild
points, Series C's tracker frame) of 1,000, 3,000 and 12,000 poses, and the real Series B and C beside
it. Each step is a fresh ``jointcal`` process, as a user runs it (interpreter start, imports and the
campaign's ingest included), on one BLAS thread:

* ``fit`` (geometry + base + tool, ``specs/robot_kinematic.toml``) with an empty wild-point cache
  (``JOINTCAL_CACHE``: the first command on the measurements finds their wild points);
* ``predict`` of that model on the same campaign, after the fit (the wild points read from the cache, as
  a user's ``predict`` after ``fit`` reads them), and ``predict_cold`` with an empty cache;
* ``diagnose`` of the campaign with every pose a sample pose (10,000 at the top size);
* ``diagnose-loop`` (``robot diagnose-loop`` to its end, judged also on the real Series C), at 1,000
  and 12,000 poses and on the real series.

Wall time (one run each: the loop and the diagnoses take seconds to minutes; the machine's load is
recorded beside) and the peak resident set of the largest process (``/usr/bin/time``'s maxrss; the
diagnosis' forked workers are separate processes). The time exponent of each step is the slope of
log(time) on log(poses) over 10^3 .. 10^4 (:func:`bench.run.exponents`). The goals: fit <= 5 s,
predict <= 2 s, diagnose-loop <= 120 s, diagnosis of 10,000 poses <= 30 s, each under 1 GB. Held-out
RMS of the fit and the loop's last round are kept to show the results are the ones before (within 1 %).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
JC = str(ROOT / ".venv" / "bin" / "jointcal")
SPEC = str(ROOT / "specs" / "robot_kinematic.toml")
SIZES = (1000, 3000, 12000)
LOOP_SIZES = (1000, 12000)
GOALS = {"fit": 5.0, "predict": 2.0, "diagnose_loop": 120.0, "diagnose_10000": 30.0, "peak_gb": 1.0}


def _run(args, cache, log=None) -> dict:
    """One fresh process: wall seconds, peak RSS (MB) of the largest process, the command's stderr tail."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "JOINTCAL_CACHE": str(cache)}
    with tempfile.NamedTemporaryFile(suffix=".rss") as rss:
        t = time.perf_counter()
        p = subprocess.run(["/usr/bin/time", "-q", "-f", "%M", "-o", rss.name, *map(str, args)], env=env,
                           capture_output=True, text=True)
        dt = time.perf_counter() - t
        try:
            peak = float(Path(rss.name).read_text().split()[-1]) / 1024.0
        except (ValueError, IndexError):
            peak = float("nan")
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, args))} failed:\n{p.stderr[-2000:]}")
    return {"seconds": dt, "peak_mb": peak, "stderr_tail": p.stderr.strip().splitlines()[-1:] if p.stderr else []}


def _load() -> float:
    return os.getloadavg()[0]


def _all_sample(src: Path, dst: Path, n: int) -> Path:
    """A copy of a campaign with its first ``n`` poses, every one a sample pose (diagnosis' input)."""
    dst.mkdir(parents=True, exist_ok=True)
    for name in ("robot.toml", "campaign.toml"):
        shutil.copy(src / name, dst / name)
    poses = pd.read_csv(src / "poses.csv", dtype=str).iloc[:n].assign(set="sample")
    tracker = pd.read_csv(src / "tracker.csv", dtype=str)
    poses.to_csv(dst / "poses.csv", index=False, lineterminator="\n")
    tracker[tracker.point_id.isin(poses.point_id)].to_csv(dst / "tracker.csv", index=False, lineterminator="\n")
    return dst


def _steps(camp: Path, tmp: Path, name: str, other: Path | None, loop: bool) -> dict:
    cache = tmp / f"cache-{name}"
    fit = tmp / f"{name}_fit.json"
    out = {"fit": _run([JC, "fit", "--campaign", camp, "--spec", SPEC, "--out", fit], cache)}
    doc = json.loads(fit.read_text())
    out["fit"].update(heldout_rms_mm=doc["heldout"]["rms_after_mm"], cv_rms_mm=doc["cv_rms_mm"],
                      outliers=[o["point_id"] for o in doc["outliers"]])
    pred = [JC, "predict", "--campaign", camp, "--model", fit, "--json", tmp / f"{name}_pred.json"]
    out["predict"] = _run(pred, cache)
    out["predict_cold"] = _run(pred, tmp / f"cache-{name}-cold")
    if loop:
        args = [JC, "robot", "diagnose-loop", "--campaign", camp, "--spec", SPEC, "--json", tmp / f"{name}_loop.json",
                "--spec-out", tmp / f"{name}_loop.toml"]
        if other is not None:
            args += ["--other", other]
        out["diagnose_loop"] = _run(args, cache)
        lp = json.loads((tmp / f"{name}_loop.json").read_text())
        last = lp["rounds"][lp["final_round"] - 1]
        out["diagnose_loop"].update(rounds=len(lp["rounds"]), own_rms_mm=last["own"]["rms_mm"],
                                    recommended=[[c["label"] for c in r["recommended"]] for r in lp["rounds"]])
    return out


def run() -> dict:
    from bench.run import exponents
    from bench.ur10_scale import import_series, write_campaign

    tmp = Path(tempfile.mkdtemp(prefix="jointcal-scale-bench-"))
    try:
        real = {s: import_series(s, tmp / f"real_{s}") for s in "BC"}
        rows, made = [], {}
        for n in SIZES:
            made[n] = write_campaign(tmp / f"ur10_{n}", n, real_c=real["C"])
            print(f"bench: scale: {n} poses ...", file=sys.stderr, flush=True)
            row = {"poses": n, "load_before": _load(), "truth": {k: v for k, v in made[n].items() if k != "n"}}
            row.update(_steps(tmp / f"ur10_{n}", tmp, f"ur10_{n}", real["C"], n in LOOP_SIZES))
            n_diag = min(n, 10000)
            diag = _all_sample(tmp / f"ur10_{n}", tmp / f"diag_{n}", n_diag)
            row["diagnose"] = _run([JC, "diagnose", "--campaign", diag, "--spec", SPEC, "--json",
                                    tmp / f"diag_{n}.json", "--quiet"], tmp / f"cache-diag-{n}")
            row["diagnose"]["poses"] = n_diag
            row["load_after"] = _load()
            rows.append(row)
        series = {}
        for s in "BC":
            print(f"bench: scale: real Series {s} ...", file=sys.stderr, flush=True)
            series[s] = _steps(real[s], tmp, f"real_{s}", real["C" if s == "B" else "B"], True)
        out = {"what": "fresh jointcal processes on a simulated UR10 campaign (bench/ur10_scale.py) and the real "
                       "series; fit with an empty wild-point cache, predict after it (and cold), diagnosis with every "
                       "pose a sample, the diagnosis loop to its end (judged on the other real series)",
               "goals": GOALS, "sizes": rows, "real": series, "cpus": os.cpu_count()}
        for step in ("fit", "predict", "predict_cold", "diagnose"):
            xs = [r["poses"] if step != "diagnose" else r["diagnose"]["poses"] for r in rows]
            out[f"{step}_exponent"] = exponents(xs, [r[step]["seconds"] for r in rows], [r[step]["peak_mb"] for r in rows])
        loops = [r for r in rows if "diagnose_loop" in r]
        out["diagnose_loop_exponent"] = exponents([r["poses"] for r in loops],
                                                  [r["diagnose_loop"]["seconds"] for r in loops])
        top = rows[-1]
        out["met"] = {"fit": top["fit"]["seconds"] <= GOALS["fit"],
                      "predict": top["predict"]["seconds"] <= GOALS["predict"],
                      "diagnose_loop": top.get("diagnose_loop", {}).get("seconds", float("inf")) <= GOALS["diagnose_loop"],
                      "diagnose_10000": top["diagnose"]["seconds"] <= GOALS["diagnose_10000"],
                      "peak_gb": max(top[k]["peak_mb"] for k in ("fit", "predict", "diagnose", "diagnose_loop")
                                     if k in top) <= 1024 * GOALS["peak_gb"]}
        return out
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    from pipeline.robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    print(json.dumps(run(), indent=1, default=float))
