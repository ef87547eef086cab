"""Stage ``fleet``: the per-unit pipeline over many campaigns, and what the fleet shows.

A joint-module maker calibrates thousands of modules a week; a plant re-checks hundreds of
robots. Each unit goes through the same steps as ``make all`` does for one campaign:

* encoder module: ingest -> orders by the spec's [select] rule -> fit on the modelling runs
  -> held-out run (peak-to-peak before/after, the paper's measure) -> leave-one-run-out CV RMS
  -> compensation table -> diagnosis;
* robot: ingest -> the spec's whole model fitted on the sample poses -> error on the
  held-out target poses -> 5-fold CV RMS -> diagnosis.

:func:`process_unit` does one unit and returns plain data (no files written): it is what a
Dask worker runs. The client writes the per-unit results, ``fleet.parquet`` and the report,
so a real cluster only needs to read the campaigns, never to write.

Across the fleet:

* **out of family**: a unit whose cross-validated residual RMS (every run, or every fold of
  poses, predicted by a model fitted without it: held-out residuals, all of the unit's data
  used) lies more than :data:`Z_OUT` robust standard deviations above the fleet's median, on a log scale (modified z-score of
  Iglewicz and Hoaglin, median and MAD: a few bad units cannot hide themselves by inflating
  the spread). Residuals are compared on a log scale because they are positive and their
  spread grows with their size.
* **effects diagnosis finds most often**: every meaningful candidate of every unit's
  diagnosis, counted by effect and target.
"""

from __future__ import annotations

import glob
import logging
import os
import sys
import time

import numpy as np
import pandas as pd

from ..core.campaign import campaign_kind
from ..core.errors import InputError
from ..core.spec import parse_spec
from ..diagnosis.encoder import EncoderAdapter
from ..diagnosis.engine import diagnose as run_diagnose
from ..diagnosis.robot import RobotAdapter
from ..encoder.aliasing import OrderTooHighError
from ..encoder.compensate import compensation_table
from ..encoder.effects import EncoderData
from ..encoder.evaluate import fit_encoder_spec, model_from_result
from ..encoder.ingest import ingest_encoder
from ..robot.model.fit import robot_fit_result
from ..robot.campaign.ingest import robot_data_sets

#: robust z above which a unit's residual is out of family
Z_OUT = 3.5
#: the residual compared across the fleet: the cross-validated RMS (one held-out run alone
#: depends on how that run's unstable errors happen to line up with the model)
FAMILY_MEASURE = "cv_rms"
#: fewer units than this and no unit is flagged (a median and MAD of a handful say little)
MIN_UNITS_FOR_FAMILY = 8


# ------------------------------------------------------------------------ finding units
def find_campaigns(patterns) -> list[str]:
    """Campaign folders matching the glob ``patterns`` (sorted, each once).

    Raises InputError when a pattern matches no folder or two folders share a name (the
    unit's name is its folder's name).
    """
    found = []
    for pattern in patterns:
        hits = sorted(p for p in glob.glob(pattern) if os.path.isdir(p))
        if not hits:
            raise InputError(pattern, "matches no campaign folder (quote the pattern so the shell leaves it to jointcal)")
        found += hits
    found = sorted(dict.fromkeys(os.path.normpath(p) for p in found))
    names: dict[str, str] = {}
    for p in found:
        name = os.path.basename(p)
        if name in names:
            raise InputError(p, f"two campaigns are named {name!r} ({names[name]} and {p}): a unit is named by its folder")
        names[name] = p
    return found


# ------------------------------------------------------------------------------ one unit
def process_unit(campaign: str, spec_text: str, spec_path: str, diagnose: bool = True) -> dict:
    """The per-unit pipeline on one campaign folder; returns plain data, writes nothing.

    Parameters
    ----------
    campaign : str
        Raw campaign folder (encoder or robot), readable where this runs.
    spec_text, spec_path : str
        The spec's text (sent to the worker, which may not see the file) and its name for messages.
    diagnose : bool
        Also run ``jointcal diagnose`` on the unit (one process; the fleet is the parallelism).

    Returns
    -------
    dict with ``unit``, ``campaign``, ``status`` (``"ok"``, ``"bad input"`` or ``"failed"``),
    ``error`` (one line), ``row`` (the unit's line of fleet.parquet) and ``files``
    (name -> JSON-ready object or DataFrame, the unit's results).
    """
    unit = os.path.basename(os.path.normpath(campaign))
    out = {"unit": unit, "campaign": str(campaign), "status": "ok", "error": "", "row": {}, "files": {}}
    try:
        spec = parse_spec(spec_text, spec_path)
        spec.require_kind(campaign_kind(campaign), campaign)
        if spec.kind == "encoder":
            row, files = _encoder_unit(campaign, spec, diagnose)
        else:
            row, files = _robot_unit(campaign, spec, diagnose)
        out["row"], out["files"] = row, files
    except InputError as exc:
        out["status"], out["error"] = "bad input", exc.one_line()
    except Exception as exc:  # noqa: BLE001 - one unit's numerical failure must not stop the fleet
        out["status"], out["error"] = "failed", f"{campaign}: {type(exc).__name__}: {' '.join(str(exc).split())}"
    return out


def _diagnosis_columns(result: dict | None) -> dict:
    if result is None:
        return {"missing_effects": "", "best_effect": "", "best_gain": np.nan, "diagnosis_cv_rms": np.nan}
    found = [c for c in result["candidates"] if c["meaningful"]]
    keys = [effect_key(c) for c in found]
    return {"missing_effects": "; ".join(keys), "best_effect": keys[0] if keys else "",
            "best_gain": float(found[0]["gain"]) if found else 0.0,
            "diagnosis_cv_rms": float(result["baseline"]["cv_rms"])}


def effect_key(candidate: dict) -> str:
    """``"harmonic 6"``, ``"backlash 4"``, ``"drift"``: an effect and its target."""
    t = candidate.get("target")
    return candidate["effect"] if t is None else f"{candidate['effect']} {t}"


def _encoder_unit(campaign, spec, diagnose):
    frame = ingest_encoder(campaign)
    try:
        result = fit_encoder_spec(frame, spec)
    except OrderTooHighError as exc:
        raise spec.located(f"{campaign}: {exc}", r"^\s*(orders|n_max)\s*=") from None
    except ValueError as exc:
        raise spec.located(f"{campaign}: {exc}", r"^\s*(modelling_runs|validation_runs)\s*=") from None
    table = compensation_table(model_from_result(result), 0.1)
    files = {"model.json": result, "table.csv": table}
    diag = None
    if diagnose:
        diag = run_diagnose(EncoderAdapter(), spec, EncoderData.from_frame(frame), workers=1)
        diag = {"kind": diag.pop("kind"), "campaign": str(campaign), "spec": spec.path, **diag}
        files["diagnosis.json"] = diag
    v = result["validation"][0]
    row = {"n_runs": int(frame["run"].nunique()), "n_points": int(len(frame)),
           "orders": ",".join(str(o) for o in result["orders"]), "unit_of_error": "arcsec",
           "measure": f"peak-to-peak of validation run {v['run']}",
           "before": float(result["p2p_before_arcsec"]), "after": float(result["p2p_after_arcsec"]),
           "reduction_pct": float(result["reduction_pct"]),
           "heldout_rms_before": float(v["rms_before_arcsec"]), "heldout_rms": float(v["rms_after_arcsec"]),
           "cv_rms": float(result["cv_rms_arcsec"]), **_diagnosis_columns(diag)}
    return row, files


def _robot_unit(campaign, spec, diagnose):
    robot, (sample, target) = robot_data_sets(campaign, ("sample",), ("target",))
    result = robot_fit_result(campaign, spec, (robot, sample, target))
    files = {"fit.json": result}
    diag = None
    if diagnose:
        diag = run_diagnose(RobotAdapter(robot), spec, sample, workers=1)
        diag = {"kind": diag.pop("kind"), "campaign": str(campaign), "spec": spec.path, **diag}
        files["diagnosis.json"] = diag
    h = result.get("heldout") or {}
    nan = float("nan")
    row = {"n_runs": 0, "n_points": int(h.get("n_sample", 0) + h.get("n_target", 0)), "orders": "",
           "unit_of_error": "mm", "measure": "maximum error over the held-out target poses",
           "before": h["before"]["max_mm"] if h else nan, "after": h["after"]["max_mm"] if h else nan,
           "reduction_pct": h.get("max_reduction_pct", nan),
           "heldout_rms_before": h.get("rms_before_mm", nan), "heldout_rms": h.get("rms_after_mm", nan),
           "cv_rms": float(result["cv_rms_mm"]), **_diagnosis_columns(diag)}
    return row, files


# ---------------------------------------------------------------------------- execution
#: chunks of units a Dask worker gets over a fleet: enough that the workers end together (at the end
#: one worker can wait up to a chunk's time for the other: with 8 a worker, 1,000 modules made chunks of 7 s),
#: few enough that the scheduler's few milliseconds a task stay small against a chunk
CHUNKS_PER_WORKER = 32


def chunked(items, n_chunks: int) -> list[list]:
    """``items`` cut into at most ``n_chunks`` consecutive chunks of nearly equal length."""
    items = list(items)
    n = max(1, min(int(n_chunks), len(items)))
    size, extra = divmod(len(items), n)
    out, at = [], 0
    for k in range(n):
        step = size + (k < extra)
        if step:
            out.append(items[at:at + step])
        at += step
    return out


def process_chunk(campaigns, spec_text: str, spec_path: str, diagnose: bool = True) -> list[dict]:
    """:func:`process_unit` of each campaign of a chunk, in order (one Dask task)."""
    return [process_unit(c, spec_text, spec_path, diagnose) for c in campaigns]


def run_units(campaigns, spec_text, spec_path, diagnose=True, scheduler=None, workers=2, serial=False,
              progress=None, on_result=None) -> list[dict]:
    """Run :func:`process_unit` over ``campaigns``: on Dask, or in this process with ``serial``.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running ``dask.distributed`` scheduler (``tcp://host:8786``). Without it a
        LocalCluster of ``workers`` processes (one thread each) is started and closed here.
    progress : callable(done, total, failed), optional
    on_result : callable(result) -> result, optional
        Called in this process with each unit's result as it arrives (e.g. to write its files);
        what it returns is kept instead (e.g. the result without its files), so a long fleet
        does not hold every unit's results in memory.

    Returns
    -------
    list of :func:`process_unit` results (as ``on_result`` left them), in the order of ``campaigns``.
    """
    say = progress or (lambda done, total, failed: None)
    keep = on_result or (lambda r: r)
    total = len(campaigns)
    if serial:
        out, failed = [], 0
        for c in campaigns:
            out.append(keep(process_unit(c, spec_text, spec_path, diagnose)))
            failed += out[-1]["status"] != "ok"
            say(len(out), total, failed)
        return out
    # imported here, not at the top: dask.distributed is slow to import (docs/speed.md), which a --serial
    # run and every user of this module's statistics (fleet.report, the tests) would pay
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    # one BLAS thread per worker process: the units are the parallelism (workers inherit this)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    if scheduler:
        client = Client(scheduler, timeout="15s")
    else:
        # the worker processes are forked from this one on Linux (macOS's system libraries are not safe to
        # fork; there, and elsewhere, Dask's spawn): they start with the
        # pipeline already imported, instead of a new interpreter importing it again (spawn, Dask's default:
        # 1-2 s of each worker's start, before its first unit)
        import dask
        import multiprocessing

        # and without Dask's statistical profiler, which samples the running unit's stack every 10 ms
        # (docs/speed.md "Measurements behind the code"; it is for Dask's dashboard, not started here)
        method = "fork" if sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods() \
            else "spawn"
        with dask.config.set({"distributed.worker.multiprocessing-method": method,
                              "distributed.worker.profile.enabled": False}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
        client = Client(cluster)
    try:
        # units go in chunks (CHUNKS_PER_WORKER a worker): a task a unit pays the scheduler's round trip and
        # the result's transfer each (docs/speed.md, "Fleet at scale"); a chunk amortises them, and a worker
        # imports the pipeline once (its first chunk), not per task
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or workers)
        chunks = chunked(range(total), n_workers * CHUNKS_PER_WORKER)
        futures = client.map(process_chunk, [[campaigns[i] for i in c] for c in chunks], spec_text=spec_text,
                             spec_path=spec_path, diagnose=diagnose, pure=False)
        index = {f.key: c for f, c in zip(futures, chunks)}
        pending = as_completed(futures)
        del futures  # a future released after its result is taken frees the worker's copy
        results: list[dict | None] = [None] * total
        failed = done = 0
        for fut in pending:
            chunk = index[fut.key]
            try:
                got = fut.result()
            except Exception as exc:  # noqa: BLE001 - a lost worker: record its units, go on
                got = [{"unit": os.path.basename(os.path.normpath(campaigns[i])), "campaign": campaigns[i],
                        "status": "failed", "error": f"{campaigns[i]}: {type(exc).__name__}: {exc}", "row": {},
                        "files": {}} for i in chunk]
            fut.release()
            for i, r in zip(chunk, got):
                results[i] = keep(r)
                failed += results[i]["status"] != "ok"
                done += 1
                say(done, total, failed)
        return results
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


# --------------------------------------------------------------------------- the fleet
COLUMNS = ["unit", "campaign", "kind", "status", "error", "n_runs", "n_points", "orders", "unit_of_error",
           "measure", "before", "after", "reduction_pct", "heldout_rms_before", "heldout_rms", "cv_rms",
           "missing_effects", "best_effect", "best_gain", "diagnosis_cv_rms", "robust_z", "out_of_family",
           "why_flagged"]


def fleet_table(results, kind: str, z_out: float = Z_OUT) -> pd.DataFrame:
    """One row per unit (sorted by unit), with the out-of-family flags (see :func:`flag_out_of_family`)."""
    rows = []
    for r in sorted(results, key=lambda r: r["unit"]):
        rows.append({"unit": r["unit"], "campaign": r["campaign"], "kind": kind, "status": r["status"],
                     "error": r["error"], **r["row"]})
    frame = pd.DataFrame(rows)
    for c in COLUMNS:
        if c not in frame:
            frame[c] = np.nan if c not in ("orders", "unit_of_error", "measure", "missing_effects", "best_effect",
                                            "why_flagged") else ""
    frame = flag_out_of_family(frame, z_out)
    frame["n_runs"] = frame["n_runs"].fillna(0).astype(int)
    frame["n_points"] = frame["n_points"].fillna(0).astype(int)
    for c in ("orders", "unit_of_error", "measure", "missing_effects", "best_effect"):
        frame[c] = frame[c].fillna("").astype(str)
    return frame[COLUMNS]


def flag_out_of_family(frame: pd.DataFrame, z_out: float = Z_OUT) -> pd.DataFrame:
    """Robust z of the log cross-validated RMS against the units that ran; flag those above ``z_out``.

    ``robust_z = 0.6745 (log r - median log r) / MAD(log r)`` with r = :data:`FAMILY_MEASURE`; units that did not run get NaN and
    are not flagged. With fewer than :data:`MIN_UNITS_FOR_FAMILY` units nothing is flagged.
    """
    frame = frame.copy()
    r_all = frame[FAMILY_MEASURE].astype(float)
    ok = (frame["status"] == "ok") & np.isfinite(r_all) & (r_all > 0)
    frame["robust_z"] = np.nan
    frame["out_of_family"] = False
    frame["why_flagged"] = ""
    if ok.sum() < MIN_UNITS_FOR_FAMILY:
        return frame
    logr = np.log(r_all[ok].to_numpy(float))
    med = float(np.median(logr))
    mad = float(np.median(np.abs(logr - med)))
    if mad <= 0:
        return frame
    z = 0.6745 * (logr - med) / mad
    frame.loc[ok, "robust_z"] = z
    flagged = ok.copy()
    flagged[ok] = z > z_out
    frame.loc[flagged, "out_of_family"] = True
    median = float(np.exp(med))
    for i in frame.index[flagged]:
        r = frame.loc[i]
        why = (f"cross-validated RMS {r[FAMILY_MEASURE]:.3g} {r['unit_of_error']} is {r[FAMILY_MEASURE] / median:.1f}x the "
               f"fleet median {median:.3g} (robust z {r['robust_z']:.1f} > {z_out:g})")
        why += (f"; diagnosis: {r['missing_effects']} missing" if r["missing_effects"]
                else "; diagnosis names no missing effect: look at the unit's residuals (noise, an unstable error)")
        frame.loc[i, "why_flagged"] = why
    return frame


def effect_counts(table: pd.DataFrame) -> pd.DataFrame:
    """How many units' diagnoses find each effect meaningful (most frequent first)."""
    counts: dict[str, int] = {}
    for text in table.loc[table["status"] == "ok", "missing_effects"]:
        for key in filter(None, (t.strip() for t in text.split(";"))):
            counts[key] = counts.get(key, 0) + 1
    out = pd.DataFrame(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])), columns=["effect", "units"])
    n = int((table["status"] == "ok").sum())
    out["share_pct"] = 100.0 * out["units"] / max(n, 1)
    return out


def fleet_summary(table: pd.DataFrame) -> dict:
    """The fleet in numbers (for the report and the command's last lines)."""
    ok = table[table["status"] == "ok"]
    red = ok["reduction_pct"].to_numpy(float)
    return {"units": int(len(table)), "ok": int(len(ok)), "bad_input": int((table["status"] == "bad input").sum()),
            "failed": int((table["status"] == "failed").sum()),
            "reduction_pct": {"median": float(np.median(red)) if red.size else None,
                              "p10": float(np.percentile(red, 10)) if red.size else None,
                              "min": float(red.min()) if red.size else None},
            "out_of_family": table.loc[table["out_of_family"], "unit"].tolist(),
            "family_judged": bool(len(ok) >= MIN_UNITS_FOR_FAMILY),
            "effects": effect_counts(table).to_dict(orient="records")}


class Progress:
    """Callable for :func:`run_units` that prints a line every 5 % (or 10 s) to a writer."""

    def __init__(self, echo, every_s: float = 10.0):
        self.echo, self.every_s = echo, every_s
        self.t0 = self.last = time.perf_counter()

    def __call__(self, done, total, failed):
        now = time.perf_counter()
        if done == total or done % max(1, total // 10) == 0 or now - self.last > self.every_s:
            self.last = now
            rate = done / max(now - self.t0, 1e-9)
            left = (total - done) / rate if rate > 0 else float("nan")
            self.echo(f"  fleet: {done}/{total} units done, {failed} not ok, {now - self.t0:.0f} s"
                      + (f", about {left:.0f} s left" if done < total else ""))
