"""A program by extension (one file or a folder), and the filtered files written all or none."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from ..core.errors import InputError
from .model import Program
from .text import read_source

#: extensions read, and the format each names
EXTENSIONS = {".src": "krl", ".mod": "rapid", ".prg": "rapid", ".sys": "rapid", ".modx": "rapid", ".ls": "fanuc",
              ".script": "ur", ".urscript": "ur"}
KNOWN = ".src (KUKA KRL, with its .dat), .mod/.prg/.sys/.modx (ABB RAPID), .ls (FANUC TP ASCII) or .script/.urscript (URScript)"


def _reader(fmt: str):
    if fmt == "krl":
        from . import krl as reader
    elif fmt == "rapid":
        from . import rapid as reader
    elif fmt == "fanuc":
        from . import fanuc as reader
    else:
        from . import urscript as reader
    return reader


def program_files(path) -> tuple[str, list[Path]]:
    """The format and the program files of ``path``: a file, or every program file of a folder.

    A folder holds one program in one language: its files and those of its sub-folders (a controller
    backup's ``RAPID/TASK1`` with ``PROGMOD`` and ``SYSMOD``), in order of their paths (a KRL ``.dat``
    goes with its ``.src``, ``$config.dat`` is read for its data). InputError for an unknown
    extension, a folder without program files, or a folder of several languages.
    """
    path = Path(path)
    if not path.is_dir():
        ext = path.suffix.lower()
        if ext not in EXTENSIONS:
            raise InputError(path, f"unknown program extension '{ext}': {KNOWN}", None, None)
        return EXTENSIONS[ext], [path]
    files = sorted((f for f in path.rglob("*") if f.is_file() and f.suffix.lower() in EXTENSIONS),
                   key=lambda f: f.relative_to(path).as_posix())
    if not files:
        raise InputError(path, f"no program file in the folder ({KNOWN})", None, None)
    fmts = sorted({EXTENSIONS[f.suffix.lower()] for f in files})
    if len(fmts) > 1:
        raise InputError(path, f"the folder holds programs in several languages ({', '.join(fmts)}); a folder is one "
                         "program: give one file or a folder of one language", None, None)
    return fmts[0], files


def read_program(path) -> Program:
    """Read a program: one file (the format told by the extension) or a folder (:func:`program_files`).

    RAPID modules of a folder are read together (a target may be declared in another module); KRL
    ``.src`` files each with their ``.dat``, and the folder's (or the ``.src``'s folder's)
    ``$config.dat`` for ``TOOL_DATA``, ``BASE_DATA``, ``LOAD_DATA`` and global positions; FANUC and
    URScript files one after the other. The motions are in file order, then in each file's order.
    """
    fmt, files = program_files(path)
    reader = _reader(fmt)
    if fmt == "rapid":
        program = reader.read_modules(files)
    elif fmt == "krl" and Path(path).is_dir():
        configs = sorted(f for f in Path(path).rglob("*") if f.name.lower() == reader.CONFIG_DAT and f.is_file())
        dats = sorted((f for f in Path(path).rglob("*") if f.is_file() and f.suffix.lower() == ".dat"
                       and f.name.lower() != reader.CONFIG_DAT), key=lambda f: f.relative_to(path).as_posix())
        shared = [f for f in dats if reader.is_public(f)]
        progs = [reader.read(f, configs[0] if configs else None, shared) for f in files]
        # every .dat of the folder is part of the program: one no .src uses is written as given
        progs.append(Program(fmt, [read_source(f) for f in dats], [], []))
        program = merge(fmt, progs)
    else:
        program = merge(fmt, [reader.read(f) for f in files])
    if Path(path).is_dir():
        root = Path(path).resolve()
        for s in program.sources:
            sp = Path(s.path).resolve()
            if root in sp.parents:
                s.rel = sp.relative_to(root).as_posix()
    return program


def merge(fmt: str, programs: list[Program]) -> Program:
    """One program of several read one by one (a file read by two of them, e.g. ``$config.dat``, once)."""
    if len(programs) == 1:
        return programs[0]
    sources, index, targets, notes = [], {}, [], []
    for prog in programs:
        remap = {}
        for k, s in enumerate(prog.sources):
            key = str(Path(s.path).resolve())
            if key not in index:
                index[key] = len(sources)
                sources.append(s)
            remap[k] = index[key]
        for t in prog.targets:
            for n in t.numbers:
                n.file = remap[n.file]
            if t.decl:
                t.decl = (remap[t.decl[0]], *t.decl[1:])
            targets.append(t)
        notes += prog.notes
    return Program(fmt, sources, targets, notes)


def write_all(out_dir, program: Program, texts: list[str]) -> list[Path]:
    """Write the program's files under their own names into ``out_dir``: all of them or none.

    A program read from a folder keeps its sub-folders (``Source.rel``). Every file goes to a
    temporary file in ``out_dir`` first; only when all are written are they
    renamed, so an error leaves no file of the program in ``out_dir``.
    """
    out_dir = Path(out_dir)
    for s in program.sources:
        root = Path(s.path).resolve().parents[len(Path(s.rel).parts) - 1] if s.rel else None
        if s.writable and root is not None and (out_dir.resolve() == root or root in out_dir.resolve().parents):
            raise InputError(s.path, f"--out {out_dir} is inside the program's own folder {root}: the filtered program "
                             "would be read as part of it next time; give another folder", None, None)
        if s.writable and Path(s.path).resolve().parent == out_dir.resolve():
            raise InputError(s.path, f"--out {out_dir} is the program's own folder: the filtered program would "
                             "overwrite it; give another folder", None, None)
    out_dir.mkdir(parents=True, exist_ok=True)
    temps, finals = [], []
    try:
        for s, text in zip(program.sources, texts):
            if not s.writable:
                continue
            final = out_dir / (s.rel or Path(s.path).name)
            final.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent)
            with os.fdopen(fd, "wb") as handle:
                handle.write(s.encode(text))
            os.chmod(tmp, 0o644)
            temps.append(tmp)
            finals.append(final)
        for final in finals:
            if final.is_dir():
                raise InputError(final, "a folder is in the way of the filtered file; nothing was written", None, None)
    except BaseException:
        for tmp in temps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise
    _install(temps, finals)
    return finals


def _install(temps: list, finals: list) -> None:
    """Rename the temporary files to their final names; on any failure every final name holds what it
    held before (the files it replaced are kept aside until all renames are done)."""
    kept, done = {}, []
    try:
        for final in finals:
            if final.exists():
                fd, aside = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".old", dir=final.parent)
                os.close(fd)
                os.replace(final, aside)
                kept[final] = aside
        for tmp, final in zip(temps, finals):
            os.replace(tmp, final)
            done.append(final)
    except BaseException:
        for final in done:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(final)
        for final, aside in kept.items():
            os.replace(aside, final)
        for tmp in temps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise
    for aside in kept.values():
        with contextlib.suppress(FileNotFoundError):
            os.unlink(aside)
