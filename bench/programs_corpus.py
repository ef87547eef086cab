"""Identity ``jointcal correct --program`` over public robot programs: ``python -m bench.programs_corpus``.

For each repository fetched as a bare git dir under ``/work/.mirror/<owner>+<name>/`` (a repository
not present is named and skipped), the robot program files of its newest commit are extracted
(``git ls-tree -r`` / ``git show``, never a work tree): KRL ``.src`` with the ``.dat`` and
``$config.dat`` of its folder (a folder per program), RAPID ``.mod/.modx/.prg/.sys`` (a folder per
program directory), FANUC ``.ls`` and URScript ``.script/.urscript`` one file each. Each is filtered by
``jointcal correct --program`` with an identity model (every parameter zero: a KR210 for KRL, RAPID
and FANUC, a UR10 for URScript), and the table ``results/programs_corpus.md`` gives per program:
repo, path, vendor, outcome (filtered: a target corrected / passed through: nothing to correct /
refused, with the one-line reason), and the bytes changed under identity (must be 0).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MIRROR = Path(os.environ.get("JOINTCAL_MIRROR", "/work/.mirror"))
OUT = ROOT / "results" / "programs_corpus.md"
#: repositories read, and the licence of each (checked in its LICENSE, or its package.xml where it has none; a
#: repository whose licence allows no use is not listed; its programs are never copied into the project)
LICENCES = {
    # KUKA KRL
    "ros-industrial/kuka_experimental": "Apache-2.0",
    "fzi-forschungszentrum-informatik/kuka_rsi_driver": "BSD-3-Clause",
    "tingelst/kuka_eki": "Apache-2.0",
    "wingljj/Kuka-RSI-real-time-control": "MIT",
    "cjlh/kuka-rsi-ros-interface": "GPL-3.0",
    "kroshu/kuka-external-control-sdk": "Apache-2.0",
    # ABB RAPID
    "ros-industrial/abb_driver": "BSD-3-Clause (package.xml, README)",
    "ros-industrial/abb_libegm": "BSD-3-Clause",
    "ros-industrial/abb_robot_driver": "BSD-3-Clause",
    "rparak/ABB-RobotStudio-SortingProductionLine": "MIT",
    "rparak/ABB-RobotStudio-YUMI": "MIT",
    "rparak/ABB-RobotStudio-YUMI-Tower-of_Hanoi": "MIT",
    "rparak/ABB_EGM_Python": "MIT",
    "rparak/OpenTube_Version_ABB": "MIT",
    "rparak/VInRoS_ABB_RS": "MIT",
    "rpiRobotics/abb_motion_program_exec": "Apache-2.0",
    # FANUC TP
    "ros-industrial/fanuc": "BSD-3-Clause",
    "rpiRobotics/fanuc_motion_program_exec": "Apache-2.0",
    "djfacio/fanuc-ai-tp": "MIT",
    "kobbled/tp_plus": "Apache-2.0",
    "onerobotics/go-fanuc": "MIT",
    "airo-ugent/airo-fanuc": "Apache-2.0",
    # Universal Robots URScript
    "UniversalRobots/Universal_Robots_ROS_Driver": "Apache-2.0",
    "UniversalRobots/Universal_Robots_Client_Library": "Apache-2.0",
    "UniversalRobots/URScript_Examples": "BSD-3-Clause",
    "rparak/URScript_Examples": "MIT",
    "Hirebotics/urscript-tools": "MIT",
    "o2ac/o2ac-ur": "MIT",
    "SintefManufacturing/python-urx": "LGPL-3.0",
}
REPOS = list(LICENCES)
#: files with a program extension that are not programs of any robot (a Go module file is no RAPID module)
NOT_PROGRAMS = {"go.mod"}
VENDOR = {".src": "KRL", ".dat": "KRL", ".mod": "RAPID", ".modx": "RAPID", ".prg": "RAPID", ".sys": "RAPID",
          ".ls": "FANUC", ".script": "URScript", ".urscript": "URScript"}


def _git(gd, *args) -> bytes:
    return subprocess.run(["git", "--git-dir", str(gd), *args], check=True, capture_output=True).stdout


def programs_of(gd: Path) -> list[tuple[str, str, list[str]]]:
    """(vendor, program path, files) of a bare repository's HEAD."""
    files = _git(gd, "ls-tree", "-r", "--name-only", "HEAD").decode("utf-8", "replace").splitlines()
    by_dir = defaultdict(list)
    for f in files:
        ext = Path(f).suffix.lower()
        if ext in VENDOR and Path(f).name.lower() not in NOT_PROGRAMS:
            by_dir[(VENDOR[ext], str(Path(f).parent))].append(f)
    out = []
    for (vendor, d), fs in sorted(by_dir.items()):
        if vendor == "KRL":
            if any(f.lower().endswith(".src") for f in fs):
                out.append((vendor, d, fs))
        elif vendor == "RAPID":
            out.append((vendor, d, fs))
        else:
            out += [(vendor, f, [f]) for f in fs]
    return out


def identity_models(tmp: Path) -> dict:
    """An identity model (every parameter zero) of a KR210 and a UR10, as the tests build them."""
    sys.path.insert(0, str(ROOT / "tests"))
    from conftest import cli_invoker
    from test_programs import KR210, SPEC, UR10

    import pandas as pd
    run = cli_invoker()
    (tmp / "spec.toml").write_text(SPEC)
    models = {}
    for name, robot, extra in (("kr210", KR210, []), ("ur10", UR10, ["--robot", UR10])):
        cell = tmp / name
        cell.mkdir()
        shutil.copy(robot, cell / "robot.toml")
        assert run("simulate", "robot", "--campaign", cell, "--truth", tmp / f"{name}.json", "--seed", "3",
                   *extra).exit_code == 0
        poses = pd.read_csv(cell / "poses.csv")
        poses[poses["set"] != "repeat"][["point_id", "set"] + [f"q{j}" for j in range(1, 7)] + ["payload_kg"]].to_csv(
            tmp / f"{name}_poses.csv", index=False)
        assert run("simulate", "measure", "--truth", tmp / f"{name}.json", "--poses", tmp / f"{name}_poses.csv",
                   "--campaign", tmp / f"{name}_meas").exit_code == 0
        r = run("fit", "--campaign", tmp / f"{name}_meas", "--spec", tmp / "spec.toml", "--out", tmp / f"{name}_fit.json")
        assert r.exit_code == 0, r.output
        fit = json.loads((tmp / f"{name}_fit.json").read_text())
        (tmp / f"{name}_id.json").write_text(json.dumps(dict(fit, parameters=[dict(p, value=0.0) for p in fit["parameters"]])))
        models[name] = tmp / f"{name}_id.json"
    return models


def _changed(a: Path, b: Path) -> int:
    """Bytes that differ between two trees (a file missing in ``b`` counts all its bytes)."""
    n = 0
    for f in a.rglob("*"):
        if f.is_file():
            g = b / f.relative_to(a)
            x = f.read_bytes()
            y = g.read_bytes() if g.exists() else b""
            n += sum(p != q for p, q in zip(x, y)) + abs(len(x) - len(y))
    return n


def run_one(gd, vendor, path, files, models, tmp) -> dict:
    prog = tmp / "prog"
    out = tmp / "out"
    shutil.rmtree(prog, ignore_errors=True), shutil.rmtree(out, ignore_errors=True)
    for f in files:
        dst = prog / Path(f).relative_to(path if vendor in ("KRL", "RAPID") else Path(f).parent)
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_bytes(_git(gd, "show", f"HEAD:{f}"))
    given = prog if vendor in ("KRL", "RAPID") else prog / Path(path).name
    model = models["ur10" if vendor == "URScript" else "kr210"]
    frame = "0 0 0 1 0 0 0" if vendor == "RAPID" else "0 0 0 0 0 0"        # a pose in the program's own form
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    cmd = [sys.executable, "-c", "import sys; from pipeline.cli import main; sys.argv[0] = 'jointcal'; main()", "correct", "--model", str(model), "--program", str(given),
           "--out", str(out), "--json", str(tmp / "r.json"), "--payload", "0", "--tool", frame, "--base", frame]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    row = {"vendor": vendor, "path": path, "files": len(files)}
    if r.returncode != 0:
        err = [x for x in r.stderr.splitlines() if "error" in x.lower()] or r.stderr.strip().splitlines()[-1:] or ["?"]
        row.update(outcome="refused", changed="", reason=err[-1].replace(str(prog), "").replace("|", "/")[:200])
        return row
    counts = json.loads((tmp / "r.json").read_text()).get("counts", {})
    row.update(outcome="filtered" if counts.get("ok") else "passed through", changed=_changed(prog, out),
               reason=", ".join(f"{k} {v}" for k, v in sorted(counts.items()) if v))
    return row


def main(repos=REPOS) -> Path:
    tmp = Path(tempfile.mkdtemp(prefix="jointcal-corpus-"))
    rows, missing = [], []
    try:
        models = identity_models(tmp)
        for repo in repos:
            here = MIRROR / repo.replace("/", "+")
            # a bare git dir, or a clone's .git (some snapshots are clones with a work tree)
            gd = next((g for g in (here / "repo", here / "repo" / ".git", here) if (g / "HEAD").exists()), here)
            if not (gd / "HEAD").exists():
                print(f"programs_corpus: {repo} not fetched under {MIRROR}; skipped", file=sys.stderr)
                missing.append(repo)
                continue
            for vendor, path, files in programs_of(gd):
                rows.append({"repo": repo, **run_one(gd, vendor, path, files, models, tmp)})
                print(f"{repo} {path}: {rows[-1]['outcome']} {rows[-1]['changed']}", file=sys.stderr)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    summary = Counter((r["vendor"], r["outcome"]) for r in rows)
    lines = ["# Identity `jointcal correct --program` over public robot programs", "",
             "`python -m bench.programs_corpus` (bench/programs_corpus.py). Bytes changed must be 0. A program is a file "
             "(FANUC, URScript) or a folder (KRL `.src` files with their `.dat`, RAPID modules).", "",
             "| vendor | programs | files | filtered | passed through | refused | bytes changed (sum) |",
             "|---|---|---|---|---|---|---|"]
    for v in sorted({r["vendor"] for r in rows}):
        mine = [r for r in rows if r["vendor"] == v]
        lines.append(f"| {v} | {len(mine)} | {sum(r['files'] for r in mine)} | {summary[(v, 'filtered')]} | "
                     f"{summary[(v, 'passed through')]} | {summary[(v, 'refused')]} | "
                     f"{sum(r['changed'] or 0 for r in mine)} |")
    lines += ["", "| repository | licence | programs |", "|---|---|---|"]
    lines += [f"| {repo} | {LICENCES.get(repo, '?')} | {sum(r['repo'] == repo for r in rows)} |" for repo in repos
              if repo not in missing]
    if missing:
        lines += ["", "Not fetched (skipped): " + ", ".join(missing)]
    lines += ["", "| repo | path | vendor | outcome | bytes changed | reason / counts |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['repo']} | {r['path']} | {r['vendor']} | {r['outcome']} | {r['changed']} | {r['reason']} |" for r in rows]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text("\n".join(lines) + "\n")
    return OUT


if __name__ == "__main__":
    print(main(sys.argv[1:] or REPOS))
