"""Fleet at scale (issue #6): 1,000 simulated joint modules through the per-unit pipeline,
in one process and on a local Dask cluster, with the speed-up: ``run() -> dict``.

Each unit runs what ``make all`` runs for one module (ingest, orders by the paper's rule, fit,
held-out run, leave-one-run-out CV, compensation table, diagnosis). The one-process run calls
:func:`pipeline.fleet.engine.run_units` with ``serial=True`` (no Dask); the cluster run starts a
LocalCluster of one single-threaded worker process per core, sends the units, gathers the
results and closes the cluster: the wall time includes starting and stopping it. Files are not
written in either (the client writes them the same way in both; see ``jointcal fleet``).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

UNITS = 1000
SEED = 99


def _simulate(folder: Path, n: int, seed: int) -> list[str]:
    from pipeline.encoder.simulate import simulate_fleet, write_encoder_campaign

    return [str(write_encoder_campaign(folder, name, frame)) for name, frame, _truth in simulate_fleet(n, seed)]


def _pool_ceiling(campaigns, spec_text, spec_path, workers) -> dict:
    """Speed-up of a plain multiprocessing pool (fork, one unit per task) over one process, 200 units."""
    import multiprocessing as mp
    from functools import partial

    from pipeline.fleet.engine import process_unit

    job = partial(process_unit, spec_text=spec_text, spec_path=spec_path)
    t = time.perf_counter()
    for c in campaigns:
        job(c)
    one = time.perf_counter() - t
    t = time.perf_counter()
    with mp.get_context("fork").Pool(workers) as pool:
        pool.map(job, campaigns, chunksize=1)
    pooled = time.perf_counter() - t
    return {"units": len(campaigns), "one_process_seconds": one, "pool_seconds": pooled, "speedup": one / pooled,
            "what": "multiprocessing.Pool (fork) of one process per core on the same units: what this machine "
                    "allows without a scheduler"}


def run(units: int = UNITS) -> dict:
    from pipeline.fleet.engine import fleet_summary, fleet_table, run_units
    from pipeline.robot.model.lm import limit_blas_threads

    limit_blas_threads(1)
    spec_path = "specs/encoder_paper.toml"
    spec_text = Path(spec_path).read_text()
    workers = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        campaigns = _simulate(Path(tmp), units, SEED)
        simulate_s = time.perf_counter() - t
        t = time.perf_counter()
        serial = run_units(campaigns, spec_text, spec_path, serial=True)
        serial_s = time.perf_counter() - t
        t = time.perf_counter()
        dask = run_units(campaigns, spec_text, spec_path, workers=workers)
        dask_s = time.perf_counter() - t
        t = time.perf_counter()
        run_units(campaigns[:200], spec_text, spec_path, workers=workers, diagnose=False)
        nodiag_s = time.perf_counter() - t
        # the machine's ceiling for the same work without Dask: a plain process pool on 200 units
        ceiling = _pool_ceiling(campaigns[:200], spec_text, spec_path, workers)
    same = fleet_table(serial, "encoder").equals(fleet_table(dask, "encoder"))
    summary = fleet_summary(fleet_table(dask, "encoder"))
    return {
        "what": f"{units} simulated joint modules (seed {SEED}), full per-unit pipeline incl. diagnosis",
        "units": units, "workers": workers, "cores": os.cpu_count(),
        "simulate_seconds": simulate_s,
        "one_process_seconds": serial_s, "one_process_units_per_s": units / serial_s,
        "dask_local_cluster_seconds": dask_s, "dask_units_per_s": units / dask_s,
        "speedup": serial_s / dask_s, "ideal_speedup": workers,
        "same_results_both_ways": bool(same),
        "dask_200_units_without_diagnosis_seconds": nodiag_s,
        "process_pool_ceiling": ceiling,
        "ok_units": summary["ok"], "out_of_family": len(summary["out_of_family"]),
        "most_frequent_missing_effects": summary["effects"][:3],
        "note": "wall times include starting and closing the LocalCluster (about 2-3 s); "
                "per-unit results are returned to the client, not written",
    }


if __name__ == "__main__":
    import json
    import sys

    n = int(sys.argv[1]) if len(sys.argv) > 1 else UNITS
    print(json.dumps(run(n), indent=2, default=float))
