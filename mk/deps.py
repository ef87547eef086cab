"""Write mk/deps.mk: for every ``jointcal`` command, the ``pipeline/**/*.py`` files it may run.

Make's stage rules depend on ``$(CODE.<module>.<function>)``, the command ``<function>`` of
``pipeline/cli/<module>.py`` (e.g. ``$(CODE.encoder.select)``, ``$(CODE.robot.calibrate_cmd)``),
so editing any module a stage uses reruns that stage. The files come from the package's own
import statements (read with :mod:`ast`, never imported: this runs with any Python 3, before
the virtual environment exists):

* what starting ``jointcal`` loads: ``pipeline/__init__.py``, ``pipeline/cli/__init__.py`` and the
  module-level imports of every command module, followed through;
* the command's own closure: the imports inside the command's body, and those of the module-level
  functions of the command line it calls (found by name, also across ``pipeline/cli`` modules);
* below the command line the closure is by module: every import of a library module counts,
  at the top or inside a function, followed through to the end (and every parent package's
  ``__init__.py``, which Python runs first).

Usage: ``python3 mk/deps.py [ROOT] > mk/deps.mk`` (ROOT: the repository, default this file's parent's).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

PACKAGE = "pipeline"
CLI = f"{PACKAGE}.cli"


class Module:
    """One module of the package: its file, its imports, and (command line) its functions' imports."""

    def __init__(self, name: str, path: Path, is_package: bool):
        self.name, self.path, self.is_package = name, path, is_package
        self.tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        self.all_imports: set[str] = set()               # anywhere in the module
        self.top_imports: set[str] = set()               # outside function bodies (run on import)
        self.functions: dict[str, ast.AST] = {}          # top-level functions and classes
        self.bound: dict[str, tuple[str, str]] = {}      # top-level `from M import n [as a]`: a -> (M, n)

    @property
    def package(self) -> str:
        return self.name if self.is_package else self.name.rpartition(".")[0]


def discover(root: Path) -> dict[str, Module]:
    modules = {}
    for path in sorted((root / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        modules[".".join(parts)] = Module(".".join(parts), path, is_package)
    return modules


def resolve(mod: Module, node: ast.ImportFrom | ast.Import, modules) -> list[tuple[str, str | None]]:
    """(module, name imported from it or None) for every package module an import statement names."""
    out = []
    if isinstance(node, ast.Import):
        for alias in node.names:
            if alias.name == PACKAGE or alias.name.startswith(PACKAGE + "."):
                out.append((alias.name, None))
        return out
    if node.level:
        base = mod.package.split(".")
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    if not (target == PACKAGE or target.startswith(PACKAGE + ".")):
        return out
    for alias in node.names:
        sub = f"{target}.{alias.name}"
        out.append((sub, None) if sub in modules else (target, alias.name))
    return out


def with_parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[: k + 1]) for k in range(len(parts))]


def analyse(modules: dict[str, Module]) -> None:
    for mod in modules.values():
        for stmt in mod.tree.body:
            if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                mod.functions[stmt.name] = stmt
        for node in ast.walk(mod.tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target, _ in resolve(mod, node, modules):
                    mod.all_imports.add(target)
        for node in _outside_functions(mod.tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target, name in resolve(mod, node, modules):
                    mod.top_imports.add(target)
                    if name is not None:
                        alias = next(a.asname or a.name for a in node.names if a.name == name)
                        mod.bound[alias] = (target, name)


def _outside_functions(tree):
    """Every node that runs when the module is imported (function bodies excluded, their
    decorators and default values included)."""
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        yield node
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            stack += list(getattr(node, "decorator_list", [])) + list(node.args.defaults) + \
                [d for d in node.args.kw_defaults if d is not None]
            continue
        stack += list(ast.iter_child_nodes(node))


def library_closure(names, modules) -> set[str]:
    """Every module ``names`` may run, following every import of every module (and parent packages)."""
    seen: set[str] = set()
    todo = [p for n in names for p in with_parents(n) if p in modules]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo += [p for n in modules[name].all_imports for p in with_parents(n) if p in modules and p not in seen]
    return seen


def is_cli(name: str) -> bool:
    return name == CLI or name.startswith(CLI + ".")


def entry_closure(modules) -> set[str]:
    """What ``jointcal`` loads before any command runs: the command line's module-level imports,
    followed through (command-line modules by their top level only, the library entirely)."""
    seen, library = set(), set()
    todo = with_parents(CLI)
    while todo:
        name = todo.pop()
        if name in seen or name not in modules:
            continue
        seen.add(name)
        for target in modules[name].top_imports:
            for p in with_parents(target):
                if p not in modules:
                    continue
                (todo.append(p) if is_cli(p) else library.add(p))
    return seen | library_closure(library, modules)


def command_closure(modules, module: str, function: str) -> set[str]:
    """The modules a command-line function may run beyond the entry's: the imports in its body and
    in the command-line functions it calls, followed through."""
    seen_functions: set[tuple[str, str]] = set()
    library: set[str] = set()
    todo = [(module, function)]
    while todo:
        mod_name, fn = todo.pop()
        if (mod_name, fn) in seen_functions:
            continue
        seen_functions.add((mod_name, fn))
        mod = modules[mod_name]
        node = mod.functions[fn]
        for sub in ast.walk(node):
            if isinstance(sub, (ast.Import, ast.ImportFrom)):
                for target, name in resolve(mod, sub, modules):
                    if is_cli(target) and name in getattr(modules.get(target), "functions", {}):
                        todo.append((target, name))
                    elif is_cli(target):
                        library |= {t for t in modules[target].all_imports if not is_cli(t)}
                    else:
                        library.add(target)
            elif isinstance(sub, ast.Name):
                if sub.id in mod.functions and sub.id != fn:
                    todo.append((mod_name, sub.id))
                elif sub.id in mod.bound:
                    target, name = mod.bound[sub.id]
                    if is_cli(target) and name in modules[target].functions:
                        todo.append((target, name))
    return library_closure(library, modules)


def is_command(node) -> bool:
    """A click command or group: decorated with ``<x>.command(...)`` or ``<x>.group(...)``."""
    for dec in getattr(node, "decorator_list", []):
        call = dec.func if isinstance(dec, ast.Call) else dec
        if isinstance(call, ast.Attribute) and call.attr in ("command", "group"):
            return True
    return False


def main(root: Path) -> str:
    modules = discover(root)
    analyse(modules)
    entry = entry_closure(modules)

    def files(names):
        return sorted(str(modules[n].path.relative_to(root)) for n in names)

    lines = ["# Generated by mk/deps.py from the import statements of pipeline/ (do not edit: `make` rewrites",
             "# it when a module changes). CODE.<module>.<command>: the files the command <command> of",
             "# pipeline/cli/<module>.py may run; a stage depends on its command's list.", ""]
    for name in sorted(n for n in modules if is_cli(n) and n != CLI):
        short = name[len(CLI) + 1:]
        for fn, node in modules[name].functions.items():
            if not is_command(node):
                continue
            code = files(entry | command_closure(modules, name, fn))
            lines.append(f"CODE.{short}.{fn} := \\\n  " + " \\\n  ".join(code))
    lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    here = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent
    sys.stdout.write(main(here))
