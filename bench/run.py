"""``make bench``: speed and scale of jointcal, written to results/bench.json.

Speed goals are shown here, never by timed unit tests. Each measurement runs in this
process after set-up (imports done), with wall time from perf_counter and peak memory of
the measured call from tracemalloc (Python allocations, numpy included), in a separate
call so that tracing does not slow the timed one.

Jobs: ``encoder``, ``make`` and ``harmonic`` live here; the others are optional modules
``bench/<module>.py`` with ``run() -> dict`` (see :data:`OPTIONAL_JOBS`), registered when
they import. ``--only`` / ``--skip`` take job names. Every robot job sets one BLAS thread.
"""

from __future__ import annotations

import argparse
import gc
import importlib
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


def exponents(sizes, seconds, peak_mb=None) -> dict:
    """Fitted exponents of time (and memory) against size: the least-squares slope of
    log(time) on log(size) over all points and the slope over the last two (top decade)."""
    x, y = np.log(np.asarray(sizes, float)), np.log(np.asarray(seconds, float))
    out = {"time_exponent_fit": float(np.polyfit(x, y, 1)[0]) if len(x) > 1 else None,
           "time_exponent_top_decade": float(np.polyfit(x[-2:], y[-2:], 1)[0]) if len(x) > 1 else None}
    if peak_mb is not None and len(x) > 1:
        m = np.log(np.asarray(peak_mb, float))
        out["memory_exponent_fit"] = float(np.polyfit(x, m, 1)[0])
        out["memory_exponent_top_decade"] = float(np.polyfit(x[-2:], m[-2:], 1)[0])
    return out


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
    from pipeline.core.spec import load_spec
    from pipeline.encoder.compensate import compensation_table
    from pipeline.encoder.effects import EncoderData
    from pipeline.encoder.evaluate import fit_encoder, model_from_result
    from pipeline.encoder.harmonic import analyse_runs
    from pipeline.encoder.ingest import ingest_encoder
    from pipeline.encoder.selection import cv_select, paper_rule

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
        shutil.copytree(ROOT, dst, ignore=shutil.ignore_patterns(".venv", ".bench", ".git", "interim", "results", "reports"),
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
    from pipeline.encoder.harmonic import analyse_runs

    rows = []
    for n in sizes:
        frame = synthetic_readings(n)
        t, mem = measure(lambda: analyse_runs(frame), repeat=3 if n < 10**6 else 2)
        rows.append({"readings": len(frame), "runs": int(frame["run"].nunique()), "seconds": t, "peak_mb": mem})
    one = synthetic_readings(10**6, per_run=10**6)
    t1, mem1 = measure(lambda: analyse_runs(one), repeat=2)
    return {"what": "harmonic analysis (LSQ orders 0..17 per run + FFT), runs of 37 readings",
            "rows": rows, **exponents([r["readings"] for r in rows], [r["seconds"] for r in rows],
                                      [r["peak_mb"] for r in rows]),
            "goal_seconds_at_1e6": 1.0, "one_run_of_1e6": {"seconds": t1, "peak_mb": mem1}}


#: optional jobs: name -> module with ``run() -> dict``; a module that does not import (not
#: written yet, or a dependency missing) is skipped and the reason recorded under "skipped".
OPTIONAL_JOBS = {
    "robot": "bench.robot_bench",          # MDH and Chebyshev identification at 10^2..10^4 poses
    "lm_vs_scipy": "bench.solver_bench",   # improved L-M against scipy.optimize.least_squares
    "diagnose": "bench.diagnose_bench",    # diagnosis of a 200-pose campaign, 8 encoder runs
    "figaroh": "bench.figaroh_bench",      # FIGAROH comparison
    "fleet": "bench.fleet_bench",          # fleet of robots
    "real": "bench.real_bench",            # real UR10: import + fit of 2,773 poses, predict on 10,000
    "correct": "bench.correct_bench",      # jointcal correct of a 10,000-point program (every effect)
    "programs": "bench.programs_bench",    # jointcal correct --program: 10,000-target KRL, RAPID and FANUC programs
    "plan": "bench.plan_bench",            # planned poses against random ones (real UR10, virtual cell)
    "arms": "bench.arms_bench",            # fit and diagnosis against the joint count N = 4, 6, 7
    "scale": "bench.scale_bench",          # issue 32: fit, predict, diagnose, the loop at 1,000-12,000 UR10 poses
    "uncertainty": "bench.uncertainty_bench",  # stated parameter uncertainties against the truth, 20 virtual cells
    "acceptance": "bench.acceptance_bench",  # issue 53: simulated FANUC, KUKA, ABB cells from their URDFs, end to end
}
BUILTIN_JOBS = {"encoder": bench_encoder_chain, "make": bench_make_encoder, "harmonic": bench_harmonic_scaling}


def available_jobs():
    """(jobs, skipped): callables by name in run order, and the reason of each optional job skipped."""
    jobs, skipped = dict(BUILTIN_JOBS), {}
    for name, module in OPTIONAL_JOBS.items():
        try:
            jobs[name] = importlib.import_module(module).run
        except ImportError as exc:
            skipped[name] = f"{module} does not import: {exc}"
    return jobs, skipped


def main(argv=None):
    names = ", ".join([*BUILTIN_JOBS, *OPTIONAL_JOBS])
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="results/bench.json")
    parser.add_argument("--only", default=None, help=f"comma-separated subset of: {names}")
    parser.add_argument("--skip", default=None, help="comma-separated jobs not to run")
    args = parser.parse_args(argv)
    only = set(args.only.split(",")) if args.only else None
    skip = set(args.skip.split(",")) if args.skip else set()
    unknown = ((only or set()) | skip) - set(BUILTIN_JOBS) - set(OPTIONAL_JOBS)
    if unknown:
        parser.error(f"unknown job(s) {', '.join(sorted(unknown))}; jobs are: {names}")
    from pipeline.robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    jobs, skipped = available_jobs()
    missing = sorted((only or set()) & set(skipped))
    if missing:
        parser.exit(2, "".join(f"bench: {n} was asked for but {skipped[n]}\n" for n in missing))
    out = {"machine": {"python": sys.version.split()[0], "platform": platform.platform(), "cpus": os.cpu_count()},
           "job_seconds": {}}
    for name in [*BUILTIN_JOBS, *OPTIONAL_JOBS]:
        if (only and name not in only) or name in skip:
            continue
        if name in skipped:
            print(f"bench: {name} skipped ({skipped[name]})", file=sys.stderr, flush=True)
            out.setdefault("skipped", {})[name] = skipped[name]
            continue
        print(f"bench: {name} ...", file=sys.stderr, flush=True)
        t = time.perf_counter()
        out[name] = jobs[name]()
        out["job_seconds"][name] = time.perf_counter() - t
        print(json.dumps(out[name], indent=1, default=float)[:2000], file=sys.stderr)
    out["job_seconds"]["total"] = sum(out["job_seconds"].values())
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2, default=float) + "\n")
    print(f"wrote {args.out} ({out['job_seconds']['total']:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
