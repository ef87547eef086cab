"""The bytes `make all` writes, as a committed reference: ``tests/data/make-all.sha256``.

One line a file of ``interim/``, ``results/`` and ``reports/`` (sorted): its SHA-256 and its path.
`make test` (tests/test_reproducible.py) runs `make all` once in a scratch copy and compares what it
wrote with this reference, file by file: the same inputs give the same bytes, today and on every run
after (it used to run `make all` twice side by side and compare the two; the reference also catches a
change of the outputs that nobody meant).

A change that is meant to change what `make all` writes (a new effect, a better solver, another
branch merged) rewrites the reference, and says which files changed in its commit message:

    make reference                 # `make all` in a scratch copy, then rewrite tests/data/make-all.sha256
    python mk/reference.py diff DIR    # which files of a finished run in DIR differ from the reference

Run from the project root. ``write`` and ``diff`` take a folder that holds a finished `make all`
(``interim/``, ``results/``, ``reports/``); ``make`` runs one in a scratch copy first.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "tests" / "data" / "make-all.sha256"
OUTPUT_DIRS = ("interim", "results", "reports")
IGNORED = (".venv", ".git", ".bench", "interim", "results", "reports", "__pycache__", ".pytest_cache",
           ".hypothesis", "*.egg-info")


def scratch_copy(dst: Path, root: Path = ROOT) -> Path:
    """A copy of the project without its outputs (empty interim/, results/, reports/), sharing its .venv."""
    shutil.copytree(root, dst, symlinks=True, ignore=shutil.ignore_patterns(*IGNORED))
    for d in OUTPUT_DIRS:
        (dst / d).mkdir()
    os.symlink(root / ".venv", dst / ".venv")
    # the shared venv's stamp must stay newer than the copy's install inputs: never reinstall from here
    for f in ("pyproject.toml", "constraints.txt"):
        os.utime(dst / f, (0, 0))
    return dst


def run_make_all(folder: Path, jobs: int = 2, timeout: float = 1500) -> str:
    """`make -s -j JOBS all` in ``folder``; its output (raises RuntimeError with its tail on failure)."""
    p = subprocess.run(["make", "-s", f"-j{jobs}", "all"], cwd=folder, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True, timeout=timeout)
    if p.returncode != 0:
        raise RuntimeError(p.stdout[-3000:])
    return p.stdout


def hashes(folder: Path) -> dict[str, str]:
    """path (relative, with /) -> SHA-256 of every file `make all` wrote in ``folder``."""
    out = {}
    for d in OUTPUT_DIRS:
        for f in sorted((folder / d).rglob("*")):
            if f.is_file() and f.name != ".gitkeep":  # tracked placeholders, not written by make all
                out[f.relative_to(folder).as_posix()] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def read_reference(path: Path = REFERENCE) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            digest, name = line.split(None, 1)
            out[name] = digest
    return out


def write_reference(folder: Path, path: Path = REFERENCE) -> dict[str, str]:
    h = hashes(folder)
    path.parent.mkdir(parents=True, exist_ok=True)
    head = "# SHA-256 of every file `make all` writes (mk/reference.py; `make reference` rewrites it)\n"
    path.write_text(head + "".join(f"{d}  {n}\n" for n, d in sorted(h.items())))
    return h


def differences(folder: Path, path: Path = REFERENCE) -> list[str]:
    """What differs from the reference: one line a file (changed, missing or not in the reference)."""
    ref, got = read_reference(path), hashes(folder)
    out = [f"changed: {n}" for n in sorted(ref) if n in got and got[n] != ref[n]]
    out += [f"missing (in the reference, not written): {n}" for n in sorted(set(ref) - set(got))]
    out += [f"new (written, not in the reference): {n}" for n in sorted(set(got) - set(ref))]
    return out


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("make", "write", "diff"):
        print(__doc__, file=sys.stderr)
        return 2
    if argv[0] == "make":
        with tempfile.TemporaryDirectory(prefix="jointcal-reference-") as tmp:
            copy = scratch_copy(Path(tmp) / "repo")
            print(f"reference: make all in {copy} ...", file=sys.stderr, flush=True)
            run_make_all(copy)
            old = read_reference() if REFERENCE.exists() else {}
            new = write_reference(copy)
        changed = sorted(n for n in set(old) | set(new) if old.get(n) != new.get(n))
        print(f"{REFERENCE.relative_to(ROOT)}: {len(new)} files, {len(changed)} changed from the last reference"
              + "".join(f"\n  {n}" for n in changed))
        return 0
    folder = Path(argv[1]) if len(argv) > 1 else ROOT
    if argv[0] == "write":
        h = write_reference(folder)
        print(f"{REFERENCE.relative_to(ROOT)}: {len(h)} files from {folder}")
        return 0
    diff = differences(folder)
    print("\n".join(diff) if diff else f"{folder}: the same bytes as the reference")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
