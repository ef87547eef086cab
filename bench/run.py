"""``make bench``: speed and scale of jointcal, written to results/bench.json.

Speed goals are shown here, never by timed unit tests. Each measurement runs in this
process after set-up (imports done), with wall time from perf_counter and peak memory of
the measured call from tracemalloc (Python allocations, numpy included).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]


def measure(fn, repeat=3):
    """Best wall time of ``repeat`` calls (s) and peak traced memory of one call (MB)."""
    times = []
    for _ in range(repeat):
        gc.collect()
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    gc.collect()
    tracemalloc.start()
    fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return min(times), peak / 2**20


def synthetic_readings(n, per_run=37, seed=0):
    rng = np.random.default_rng(seed)
    runs = max(1, n // per_run)
    m = n // runs
    step = np.tile(np.arange(m), runs)
    theta = np.mod(step * (360.0 / (m - 1)) + rng.normal(0, 0.005, step.size), 360.0)
    y = 20 * np.sin(np.deg2rad(theta) * 14 + 0.3) + rng.normal(0, 1, step.size)
    return pd.DataFrame({"run": np.repeat(np.arange(1, runs + 1), m), "step": step, "theta_deg": theta,
                         "error_arcsec": y})


def bench_encoder_chain():
    """The whole encoder chain on the shipped fixture, in process (ingest -> ... -> table)."""
    from pipeline.compensate import compensation_table
    from pipeline.evaluate import fit_encoder, model_from_result
    from pipeline.harmonic import analyse_runs
    from pipeline.ingest import ingest_encoder
    from pipeline.select import cv_select, paper_rule
    from pipeline.spec import load_spec
    from pipeline.effects import EncoderData

    spec = load_spec(ROOT / "specs" / "encoder_paper.toml")

    def chain():
        for m in ("a", "b"):
            frame = ingest_encoder(ROOT / "raw" / "encoder" / m)
            h = analyse_runs(frame)
            orders, _ = paper_rule(h, [1, 2, 3, 4, 5], spec.select)
            data = EncoderData.from_frame(frame)
            cv_select(data.subset(data.run <= 5), 17)
            result = fit_encoder(frame, spec, orders)
            compensation_table(model_from_result(result), 0.1)

    t, mem = measure(chain)
    return {"what": "encoder chain on the fixture (2 modules, in process, CV selection included)",
            "seconds": t, "peak_mb": mem, "goal_seconds": 5.0}


def bench_make_encoder():
    """`make encoder` from an empty interim/results in a scratch copy (one process per stage)."""
    with tempfile.TemporaryDirectory() as tmp:
        dst = Path(tmp) / "repo"
        shutil.copytree(ROOT, dst, ignore=shutil.ignore_patterns(".venv", ".git", "interim", "results", "reports"),
                        symlinks=True)
        os.symlink(ROOT / ".venv", dst / ".venv")
        for d in ("interim", "results", "reports"):
            (dst / d).mkdir(exist_ok=True)
        t = time.perf_counter()
        subprocess.run(["make", "-s", "encoder"], cwd=dst, check=True, capture_output=True)
        first = time.perf_counter() - t
        t = time.perf_counter()
        out = subprocess.run(["make", "encoder"], cwd=dst, check=True, capture_output=True, text=True)
        second = time.perf_counter() - t
    return {"what": "make encoder (11 stage processes incl. the PDF), then make again (nothing to do)",
            "seconds": first, "second_make_seconds": second, "second_make_says": out.stdout.strip()}


def bench_harmonic_scaling(sizes=(10**3, 10**4, 10**5, 10**6)):
    from pipeline.harmonic import analyse_runs

    rows = []
    for n in sizes:
        frame = synthetic_readings(n)
        t, mem = measure(lambda: analyse_runs(frame), repeat=3 if n < 10**6 else 2)
        rows.append({"readings": len(frame), "runs": int(frame["run"].nunique()), "seconds": t, "peak_mb": mem})
    x = np.log([r["readings"] for r in rows])
    y = np.log([r["seconds"] for r in rows])
    exponent = float(np.polyfit(x[-2:], y[-2:], 1)[0]) if len(rows) > 1 else None
    one = synthetic_readings(10**6, per_run=10**6)
    t1, mem1 = measure(lambda: analyse_runs(one), repeat=2)
    return {"what": "harmonic analysis (LSQ orders 0..17 per run + FFT), runs of 37 readings",
            "rows": rows, "time_exponent_top_decade": exponent, "goal_seconds_at_1e6": 1.0,
            "one_run_of_1e6": {"seconds": t1, "peak_mb": mem1}}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="results/bench.json")
    parser.add_argument("--only", default=None, help="comma-separated subset: encoder,make,harmonic,robot")
    args = parser.parse_args(argv)
    only = set(args.only.split(",")) if args.only else None
    out = {"machine": {"python": sys.version.split()[0], "platform": platform.platform(), "cpus": os.cpu_count()}}
    jobs = {"encoder": bench_encoder_chain, "make": bench_make_encoder, "harmonic": bench_harmonic_scaling}
    try:
        from bench import robot_bench

        jobs["robot"] = robot_bench.run
    except ImportError:
        pass
    try:
        from bench import diagnose_bench

        jobs["diagnose"] = diagnose_bench.run
    except ImportError:
        pass
    for name, job in jobs.items():
        if only and name not in only:
            continue
        print(f"bench: {name} ...", file=sys.stderr, flush=True)
        out[name] = job()
        print(json.dumps(out[name], indent=1, default=float)[:2000], file=sys.stderr)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2, default=float) + "\n")
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
