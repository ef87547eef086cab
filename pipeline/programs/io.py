"""A program by extension, and the filtered files written all or none."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from ..core.errors import InputError
from .model import Program

#: extensions read, and the format each names
EXTENSIONS = {".src": "krl", ".mod": "rapid", ".ls": "fanuc", ".script": "ur"}


def read_program(path) -> Program:
    """Read a program; the format is told by the extension (InputError for another one)."""
    ext = Path(path).suffix.lower()
    fmt = EXTENSIONS.get(ext)
    if fmt is None:
        raise InputError(path, f"unknown program extension '{ext}': .src (KUKA KRL, with its .dat), .mod (ABB RAPID), "
                         ".ls (FANUC TP ASCII) or .script (URScript)", None, None)
    if fmt == "krl":
        from . import krl as reader
    elif fmt == "rapid":
        from . import rapid as reader
    elif fmt == "fanuc":
        from . import fanuc as reader
    else:
        from . import urscript as reader
    return reader.read(path)


def write_all(out_dir, program: Program, texts: list[str]) -> list[Path]:
    """Write the program's files under their own names into ``out_dir``: all of them or none.

    Every file goes to a temporary file in ``out_dir`` first; only when all are written are they
    renamed, so an error leaves no file of the program in ``out_dir``.
    """
    out_dir = Path(out_dir)
    for s in program.sources:
        if Path(s.path).resolve().parent == out_dir.resolve():
            raise InputError(s.path, f"--out {out_dir} is the program's own folder: the filtered program would "
                             "overwrite it; give another folder", None, None)
    out_dir.mkdir(parents=True, exist_ok=True)
    temps, finals = [], []
    try:
        for s, text in zip(program.sources, texts):
            fd, tmp = tempfile.mkstemp(prefix=f".{Path(s.path).name}.", suffix=".tmp", dir=out_dir)
            with os.fdopen(fd, "wb") as handle:
                handle.write(text.encode("latin-1"))
            os.chmod(tmp, 0o644)
            temps.append(tmp)
            finals.append(out_dir / Path(s.path).name)
        for tmp, final in zip(temps, finals):
            os.replace(tmp, final)
    except BaseException:
        for tmp in temps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise
    return finals
