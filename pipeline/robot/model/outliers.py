"""Wild measurements: the poses no plausible model explains, named and left out (contract section 12).

An SMR reseated, a broken beam, a swapped row: one such point among a thousand moves every number
a fit or a diagnosis decides on (3 points of 3-8 mm among 1,664 poses put 0.24 mm into a
cross-validated RMS of 0.10). They are found here, the same way by ``jointcal fit``, ``diagnose``,
``robot diagnose-loop`` and ``predict``:

1. **A model flexible enough that physics is not mistaken for a wild point** (:func:`flexible_effects`):
   geometry, base and tool, a joint map (an angle error of any shape over the joint's angle) and
   compliance on every joint, backlash on every joint approached from both sides, and the spec's
   other effects (thermal, ...). A missing effect of the kind
   diagnosis can recommend is in it, so what it leaves is noise, the effects no model here has,
   and wild points.
2. **A robust fit**: it is fitted on the sample poses, the poses it names are left out and it is
   fitted again, until the set named no longer changes (a redescending M-estimator with hard
   rejection: a wild pose gets weight 0, every other weight 1). A refit is Gauss-Newton steps from the
   fit on all sample poses, on the normal equations of the poses kept (``refit_without``). Each pose's
   residual is its 3-D distance from that model (for a pose left out, a prediction).
3. **A robust scale** of the residuals: ``sigma = sqrt(median(|r|^2) / 2.366)``, the per-axis
   standard deviation the median of the squared 3-D residual gives for Gaussian noise (2.366 is
   the median of chi-square with 3 degrees of freedom); the median is not moved by a handful of
   wild points. Targets are scaled by the targets' own residuals (they are predictions), samples
   by the samples'.
4. **The rule**: a pose is wild when its residual exceeds :data:`WILD_SIGMAS` sigma AND is not
   shared by its :data:`NEIGHBOURS` nearest sample poses in joint space (its residual less the
   neighbours' median residual also exceeds WILD_SIGMAS sigma). The second test is the local,
   nonparametric check that a pose is not the edge of a physical effect the flexible model lacks:
   physics is smooth in the joint angles, a wild point is alone.

**No scale**: when the flexible model leaves less than :data:`MIN_RESIDUAL_DOF_FRACTION` of its
residuals' degrees of freedom (a small campaign, e.g. the 20 poses ``jointcal plan`` proposes, which
it nearly interpolates), its residuals give no scale: no pose is named, and ``no_scale`` says why
(console, JSON).

More than :data:`MAX_WILD_FRACTION` of a campaign's poses wild, and more than :data:`HANDFUL`: refused
with one line (a wrong frame, unit or robot is not a handful of outliers).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ...core.parallel import can_fork, fork_process, pipe
from ...core.spec import parse_spec
from ...core.tables import text_table
from ...core.wild import HANDFUL, MAX_WILD_FRACTION, MIN_RESIDUAL_DOF_FRACTION, NEIGHBOURS, RULE, WILD_SIGMAS

#: Refits of the robust fit at most (it stops earlier when the set named no longer changes).
MAX_REFITS = 5
#: median of chi-square with 3 degrees of freedom (the squared 3-D norm of unit Gaussian noise)
CHI2_3_MEDIAN = 2.365974


@dataclass
class Wild:
    """What :func:`find_wild` found: masks of the wild sample and target poses, and the JSON list."""

    sample: np.ndarray
    target: np.ndarray
    outliers: list = field(default_factory=list)
    sigma_mm: dict = field(default_factory=dict)
    kept: bool = False
    #: why the residuals gave no scale ('' when they did; see the module docstring)
    no_scale: str = ""

    def document(self) -> dict:
        """The JSON keys (contract section 12): ``outliers``, and how they were found."""
        rule = {"rule": RULE, "sigma_mm": self.sigma_mm, "threshold_sigmas": WILD_SIGMAS, "kept": self.kept}
        if self.no_scale:
            rule["no_scale"] = self.no_scale
        return {"outliers": self.outliers, "outlier_rule": rule}

    def clean(self, sample, target):
        """The sample and target poses without the wild ones (all of them with ``kept``)."""
        if self.kept:
            return sample, target
        return (sample.subset(~self.sample) if self.sample.any() else sample,
                target.subset(~self.target) if self.target.any() else target)


#: Effects the flexible model has on every joint (a spec's own, on some joints or with other settings,
#: are replaced by them): a joint map contains a joint's harmonics and curves of any shape.
FLEXIBLE_PER_JOINT = ("joint_map", "joint_harmonic", "chebyshev", "compliance", "backlash")


def flexible_effects(robot, effects, data) -> list:
    """The flexible model (see the module docstring): geometry, base, tool, a joint map and compliance on
    every joint, backlash on every joint approached from both sides, and the spec's other effects
    (thermal, ...). The same for every spec without such other effects, so that ``fit`` with any spec,
    ``diagnose``, the loop and ``predict`` name the same points of a campaign."""
    lines = ['[[effect]]\nname = "geometry"', '[[effect]]\nname = "base"', '[[effect]]\nname = "tool"']
    # (a campaign's own tracker frame is not the robot's: each campaign is searched on its own)
    lines += [e.spec_lines() for e in effects
              if e.name not in FLEXIBLE_PER_JOINT + ("geometry", "base", "tool", "campaign_frame")]
    lines.append('[[effect]]\nname = "joint_map"')
    lines.append('[[effect]]\nname = "compliance"')
    both = [j + 1 for j in range(data.dir.shape[1]) if np.unique(data.dir[:, j]).size > 1]
    if both:
        lines.append(f'[[effect]]\nname = "backlash"\njoints = {both}')
    return list(parse_spec('[model]\nkind = "robot"\n\n' + "\n\n".join(lines) + "\n", "<flexible model>").effects)


def robust_sigma(res) -> float:
    """Per-axis standard deviation (mm) from the median squared 3-D residual (Gaussian-consistent)."""
    r2 = np.sum(np.asarray(res, float) ** 2, axis=1)
    return float(np.sqrt(np.median(r2) / CHI2_3_MEDIAN)) if r2.size else 0.0


def _scaled(q, lo, span):
    return (np.asarray(q, float) - lo) / span


def _flag(res, sigma, q, q_ref, res_ref, valid_ref, own=None) -> np.ndarray:
    """Poses whose residual exceeds WILD_SIGMAS sigma and is not shared by their nearest reference poses.

    ``own``: each pose's index among the reference poses (itself is not its own neighbour), or None.
    Reference poses not ``valid_ref`` (named wild already) are no one's neighbours."""
    from scipy.spatial import cKDTree

    size = np.linalg.norm(res, axis=1)
    big = size > WILD_SIGMAS * sigma
    ref = np.flatnonzero(valid_ref)
    if not big.any() or ref.size < 2:
        return big
    k = min(NEIGHBOURS + 1, ref.size)
    _, nb = cKDTree(q_ref[ref]).query(q[big], k=k)
    nb = ref[np.atleast_2d(nb)]
    out = big.copy()
    for row, i in enumerate(np.flatnonzero(big)):
        others = [n for n in nb[row] if own is None or n != own[i]][:NEIGHBOURS]
        local = np.median(res_ref[others], axis=0)
        out[i] = np.linalg.norm(res[i] - local) > WILD_SIGMAS * sigma
    return out


def _orientation_residuals(model, data) -> np.ndarray:
    """Orientation errors (n, 3) arcsec, measured - predicted (the turn from the predicted probe frame)."""
    from ...core.se3 import ARCSEC_PER_MRAD, orientation_errors

    R, _ = model.predict_pose(data)
    return -orientation_errors(R, data.measured_R) * ARCSEC_PER_MRAD


def tracker_lines(campaign) -> dict:
    """point_id -> line of its row in the campaign's tracker.csv (the header is line 1)."""
    path = Path(campaign) / "tracker.csv"
    try:
        table = text_table(path.read_text(encoding="utf-8"), path)
    except (OSError, ValueError, InputError, csv.Error):
        return {}
    if table is None or "point_id" not in table[0]:
        return {}
    return {p: int(line) for p, line in zip(table[0]["point_id"].str.strip(), table[1])}


# ------------------------------------------------------------------ computed once per measurements
#: Environment variable naming the folder of the wild-point cache, or ``off``; default
#: ``$XDG_CACHE_HOME/jointcal`` (``~/.cache/jointcal``).
CACHE_ENV = "JOINTCAL_CACHE"


def cache_folder() -> Path | None:
    """Where :func:`find_wild` keeps what it found (None: ``JOINTCAL_CACHE=off``)."""
    import os

    where = os.environ.get(CACHE_ENV, "")
    if where.lower() in ("off", "0", "no", "none"):
        return None
    if where:
        return Path(where)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "jointcal"


_CODE = []


def _code_fingerprint() -> str:
    """SHA-256 of the package's source (every module): a cached result is that code's on those data."""
    import hashlib

    if not _CODE:
        root = Path(__file__).resolve().parents[2]
        h = hashlib.sha256()
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
        _CODE.append(h.hexdigest())
    return _CODE[0]


def measurements_key(robot, flex, sample, target) -> str:
    """What the wild points depend on, hashed: the code, the robot, the flexible model's effects and every
    array of the sample and target poses (angles, directions, payloads, temperatures, torques, points, ids)."""
    import hashlib

    h = hashlib.sha256(_code_fingerprint().encode())
    h.update(robot.to_toml().encode())
    for e in flex:
        h.update(e.spec_lines().encode())
    for data in (sample, target):
        for a in (data.q_deg, data.dir, data.payload_kg, data.temperature_c, data.torque_nm, data.measured_mm,
                  data.lower_deg, data.upper_deg, getattr(data, "measured_R", None)):
            a = np.ascontiguousarray(np.asarray(a if a is not None else [], float))
            h.update(str(a.shape).encode() + a.tobytes())
        h.update("\0".join(map(str, data.point_id)).encode())
        h.update(str(getattr(data, "grating_joints", ())).encode())
    return h.hexdigest()


def _cached(key):
    import json

    folder = cache_folder()
    if folder is None:
        return None
    try:
        return json.loads((folder / f"wild-{key}.json").read_text())
    except (OSError, ValueError):
        return None


def _keep(key, found: dict) -> None:
    import json
    import os
    import tempfile

    folder = cache_folder()
    if folder is None:
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".wild-", suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(found, f)
        os.replace(tmp, folder / f"wild-{key}.json")
    except OSError:
        pass


def find_wild(robot, effects, sample, target, campaign=None, keep: bool = False) -> Wild:
    """The wild sample and target poses of a campaign (see the module docstring).

    Parameters
    ----------
    robot : Robot
    effects : list of RobotEffect
        The spec's (or the fitted model's) effects: the flexible model contains them.
    sample, target : RobotData
        The campaign's sample poses (fitted) and target poses (judged on the fit), mm.
    campaign : path, optional
        The campaign folder: each wild pose's tracker.csv line (0 when unknown).
    keep : bool
        ``--keep-outliers``: they are named, not left out, and never refused.

    Raises
    ------
    InputError
        More than :data:`MAX_WILD_FRACTION` of the poses wild, and more than :data:`HANDFUL` (not with
        ``keep``).
    """
    return WildSearch(robot, effects, sample, target, campaign, keep, background=False).result()


#: sample poses from which a wild search not in the cache runs in a forked process (:class:`WildSearch`), the
#: caller going on with work that does not need it (a fork costs about 0.1 s)
BACKGROUND_MIN_POSES = 2000


class WildSearch:
    """:func:`find_wild`, begun: on a campaign of :data:`BACKGROUND_MIN_POSES` sample poses or more whose wild
    points are not in the cache, the search runs in a forked process (Linux; not without ``background``) while
    the caller goes on; :meth:`result` waits for it. Otherwise it is found when asked. The result is the same
    either way (the same computation; the cache holds what it returns)."""

    def __init__(self, robot, effects, sample, target, campaign=None, keep: bool = False, background: bool = True):
        self.args = (robot, effects, sample, target, campaign, keep)
        self._found, self._proc, self._pipe, self._key = None, None, None, None
        # no search: nothing measured, or too few sample poses to give a scale
        ws, wt = np.zeros(sample.n, bool), np.zeros(target.n, bool)
        self._none = None
        if sample.measured_mm is None or sample.n == 0:
            self._none = Wild(ws, wt, [], {}, keep)
        elif sample.n < max(20, 2 * NEIGHBOURS):
            self._none = Wild(ws, wt, [], {}, keep, f"{sample.n} sample poses are too few to give a scale (20 at "
                                                    "least); none is named")
        if self._none is not None:
            return
        flex = flexible_effects(robot, effects, sample)
        self._flex = flex
        self._key = measurements_key(robot, flex, sample, target)
        self._found = _cached(self._key)
        if self._found is None and background and sample.n >= BACKGROUND_MIN_POSES:
            self._fork()

    @property
    def running(self) -> bool:
        """Whether the search runs in a forked process now."""
        return self._proc is not None

    def _fork(self) -> None:
        import sys

        if not can_fork():
            return
        sys.stdout.flush()         # the forked process flushes its copy of what is buffered when it ends
        sys.stderr.flush()
        receive, send = pipe()
        self._proc = fork_process(_search_in_background, (self.args, self._flex, self._key, send))
        send.close()
        self._pipe = receive

    def result(self) -> Wild:
        """The :class:`Wild` poses (waits for a search in a forked process)."""
        robot, effects, sample, target, campaign, keep = self.args
        if self._none is not None:
            return self._none
        if self._found is None and self._proc is not None:
            try:
                status, found = self._pipe.recv()
            except EOFError:
                status, found = "lost", None
            self._proc.join()
            self._pipe.close()
            self._proc = self._pipe = None
            if status == "error":
                raise found
            self._found = found
        if self._found is None:
            # the wild points are the measurements', not the model's: found once, kept in the cache (the same
            # result, to the bit, as finding them again), and read by every later fit, diagnose, loop or predict
            self._found = _search(robot, effects, self._flex, sample, target)
            _keep(self._key, self._found)
        return _wild(self._found, sample, target, campaign, keep)


def _search_in_background(shared) -> None:
    """The forked process of :class:`WildSearch`: the search, kept in the cache, its result sent back."""
    (robot, effects, sample, target, campaign, keep), flex, key, send = shared
    try:
        found = _search(robot, effects, flex, sample, target)
        _keep(key, found)
        send.send(("ok", found))
    except BaseException as exc:   # noqa: BLE001 - the parent raises it (an InputError is the user's one line)
        try:
            send.send(("error", exc))
        except Exception:   # noqa: BLE001 - not picklable: the parent searches itself
            send.send(("lost", None))
    finally:
        send.close()


def _wild(found: dict, sample, target, campaign, keep: bool) -> Wild:
    """The :class:`Wild` poses of a search's (or the cache's) result."""
    ws, wt = np.zeros(sample.n, bool), np.zeros(target.n, bool)
    ws[found["sample"]] = True
    wt[found["target"]] = True
    if found["no_scale"]:
        return Wild(ws, wt, [], {}, keep, found["no_scale"])
    sigma, sig_s = found["sigma"], found["sigma"]["sample"]
    lines = tracker_lines(campaign) if campaign is not None else {}
    outliers = []
    for name, mask, data in (("sample", ws, sample), ("target", wt, target)):
        for k, (i, size) in enumerate(zip(np.flatnonzero(mask), found[f"{name}_mm"])):
            pid = str(data.point_id[i])
            outliers.append({"point_id": pid, "set": name, "error_mm": float(size), "line": int(lines.get(pid, 0))})
            if f"{name}_arcsec" in found:
                outliers[-1]["orientation_error_arcsec"] = found[f"{name}_arcsec"][k]
    wild = Wild(ws, wt, outliers, sigma, keep)
    n_all = sample.n + target.n
    if not keep and len(outliers) > max(MAX_WILD_FRACTION * n_all, HANDFUL):
        worst = max(outliers, key=lambda o: o["error_mm"])
        raise InputError(Path(campaign or ".") / "tracker.csv",
                         f"{len(outliers)} of {n_all} poses ({100 * len(outliers) / n_all:.1f} %) look wild (more than "
                         f"{100 * MAX_WILD_FRACTION:g} %; the worst, {worst['point_id']}, {worst['error_mm']:.3g} mm off "
                         f"a flexible model, sigma {sig_s:.3g} mm): a wrong frame, unit or robot is not a handful of "
                         "outliers; check the campaign (or --keep-outliers)", worst["line"] or None, "x_mm")
    return wild


def interpolates(dof: float, n_poses: int, rows_per_pose: int, sigma_mm: float) -> str:
    """Why the flexible model's residuals give no scale to judge wild points by, or '' when they do (the
    rule of the module docstring: less than :data:`MIN_RESIDUAL_DOF_FRACTION` of the residuals' degrees of
    freedom left).

    Parameters
    ----------
    dof : float
        The flexible model's effective number of parameters (nan: unknown, never too many).
    n_poses : int
        Sample poses fitted.
    rows_per_pose : int
        Residual rows each pose gives the fit: 3 (a position), 6 (a 6-DoF probe's position and orientation).
    sigma_mm : float
        The residuals' robust sigma (mm), said in the reason.
    """
    rows = rows_per_pose * n_poses
    if not np.isfinite(dof) or rows - dof >= MIN_RESIDUAL_DOF_FRACTION * rows:
        return ""
    each = f"{rows_per_pose} a pose" + (": position and orientation" if rows_per_pose > 3 else "")  # noqa: PLR2004
    return (f"the flexible model ({dof:.0f} effective parameters on {n_poses} sample poses, {rows} residual rows, "
            f"{each}) leaves {100 * (rows - dof) / rows:.0f} % of its residuals' degrees of freedom, less than "
            f"{100 * MIN_RESIDUAL_DOF_FRACTION:g} %: it nearly interpolates them (robust sigma {sigma_mm:.2g} mm), "
            "so they give no scale to judge wild points by; none is named")


def _search(robot, effects, flex, sample, target) -> dict:
    """The robust fit and the rule of the module docstring: the wild sample and target poses (indices), the
    size of each (mm), the robust sigmas, or why there is no scale (JSON-ready)."""
    from .estimate import effects_estimator, fit_effects

    ws, wt = np.zeros(sample.n, bool), np.zeros(target.n, bool)
    lo = np.min(sample.q_deg, axis=0)
    span = np.maximum(np.ptp(sample.q_deg, axis=0), 1e-9)
    qs = _scaled(sample.q_deg, lo, span)
    rs = rt = None
    first = None
    for _ in range(MAX_REFITS):
        n_fitted = int(np.sum(~ws))
        if first is None:
            try:
                est = effects_estimator(robot, flex, checks=False)
                est.keep_designs = True       # the refit steps and predictions on the sample reuse its design
                first = est.fit(sample)
            except np.linalg.LinAlgError:
                first = fit_effects(robot, list(effects), sample, checks=False)
            model = first
        else:
            # the refit without the poses named: Gauss-Newton steps from the fit on all of them, on the
            # normal equations of the rest (the same model on all but a few of the same poses)
            model = first.refit_without(sample, ~ws, determined=False)
        rs = sample.measured_mm - model.predict(sample)
        sig_s = robust_sigma(rs)
        # a 6-DoF fit has an orientation's 3 rows besides the position's 3 for every pose
        per_pose = rs.shape[1] * (2 if getattr(model, "weight_", None) or getattr(first, "weight_", None) else 1)
        why = interpolates(getattr(model, "dof_", float("nan")), n_fitted, per_pose, sig_s)
        if why:
            return {"sample": [], "target": [], "sample_mm": [], "target_mm": [], "sigma": {}, "no_scale": why}
        new = _flag(rs, sig_s, qs, qs, rs, ~ws, own=np.arange(sample.n))
        if sample.has_orientation:
            # a 6-DoF probe: a pose is wild in its orientation alone too (judged on its own robust scale)
            os_ = _orientation_residuals(model, sample)
            sig_os = robust_sigma(os_)
            new = new | _flag(os_, sig_os, qs, qs, os_, ~ws, own=np.arange(sample.n))
        if np.array_equal(new, ws):
            break
        ws = new
    sigma = {"sample": sig_s}
    ori = {}
    if sample.has_orientation:
        sigma["sample_orientation_arcsec"] = sig_os
        ori["sample"] = os_
    if target.n:
        rt = target.measured_mm - model.predict(target)
        sig_t = robust_sigma(rt) if target.n >= 20 else sig_s
        sigma["target"] = sig_t
        wt = _flag(rt, sig_t, _scaled(target.q_deg, lo, span), qs, rs, ~ws)
        if target.has_orientation and sample.has_orientation:
            ot = _orientation_residuals(model, target)
            sig_ot = robust_sigma(ot) if target.n >= 20 else sig_os
            sigma["target_orientation_arcsec"] = sig_ot
            ori["target"] = ot
            wt = wt | _flag(ot, sig_ot, _scaled(target.q_deg, lo, span), qs, os_, ~ws)
    out = {"sigma": sigma, "no_scale": ""}
    for name, mask, res in (("sample", ws, rs), ("target", wt, rt)):
        idx = np.flatnonzero(mask)
        out[name] = idx.tolist()
        out[f"{name}_mm"] = [float(np.linalg.norm(res[i])) for i in idx]
        if name in ori:
            out[f"{name}_arcsec"] = [float(np.linalg.norm(ori[name][i])) for i in idx]
    return out


def describe(wild: Wild) -> str:
    """One console line naming the wild poses, or saying why there is no scale to judge them by ('' when
    there are none)."""
    if wild.no_scale:
        return f"no wild-point check: {wild.no_scale}"
    if not wild.outliers:
        return ""
    what = "kept (--keep-outliers)" if wild.kept else "left out (of fitting, registering and the errors)"
    names = ", ".join(f"{o['point_id']} ({o['set']}, tracker.csv line {o['line']}, {o['error_mm']:.3f} mm"
                      + (f", {o['orientation_error_arcsec']:.0f} arcsec" if "orientation_error_arcsec" in o else "") + ")"
                      for o in wild.outliers)
    return f"{len(wild.outliers)} wild measurement(s), {what}: {names}"
