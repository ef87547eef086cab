"""Numbers the README and docs/ quote from what `make all` writes, checked against those files.

Every quoted number is registered in ``docs/quoted-numbers.toml``: the page, a template of the
sentence or table cell that quotes it (``{}`` where each number stands) and, per ``{}``, where the
number comes from (``FILE:KEY:FORMAT``). Run from the project root:

    python mk/quotes.py [--results DIR]        # check: exit 1 and one line per stale quote
    python mk/quotes.py --fix [--results DIR]  # rewrite the quoted numbers from the results

FILE is relative to the results' root (the project root by default, so ``results/...``); KEY is a
dotted path into a JSON file (list items by index), or for a CSV file ``rows`` (the data rows) or
``count(COLUMN=VALUE)``; FORMAT is a Python format spec (``.3f``, ``,d``). `make test` runs the check
against the files of its own `make all` (tests/test_reproducible.py), and tests/test_docs.py proves
the check fails on a number that differs.
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import sys
import tomllib
from pathlib import Path

NUMBER = r"[-+−]?\d[\d,]*(?:\.\d+)?"


def value_of(root: Path, spec: str, cache: dict):
    """The number SPEC (``FILE:KEY:FORMAT``) names, formatted."""
    fname, key, fmt = spec.rsplit(":", 2)
    path = root / fname
    if path not in cache:
        text = path.read_text()
        cache[path] = json.loads(text) if path.suffix == ".json" else list(csv.DictReader(text.splitlines()))
    data = cache[path]
    if isinstance(data, list) and path.suffix == ".csv":
        if key == "rows":
            v = len(data)
        else:
            m = re.fullmatch(r"count\((\w+)=(.*)\)", key)
            if not m:
                raise ValueError(f"{spec}: a CSV key is rows or count(COLUMN=VALUE)")
            v = sum(1 for r in data if r[m.group(1)] == m.group(2))
    else:
        v = data
        for part in key.split("."):
            v = v[int(part)] if isinstance(v, list) else v[part]
    return format(v, fmt)


def render(template: str, values: list[str]) -> str:
    parts = template.split("{}")
    if len(parts) != len(values) + 1:
        raise ValueError(f"template {template!r} has {len(parts) - 1} places for {len(values)} values")
    return "".join(p + v for p, v in zip(parts, values + [""]))


def pattern(template: str) -> re.Pattern:
    return re.compile(NUMBER.join(re.escape(p) for p in template.split("{}")))


def check(project: Path, results_root: Path, registry: Path | None = None, fix: bool = False) -> list[str]:
    """Stale quotes as one line each (empty: every quote equals its file); with ``fix``, rewrite the
    stale ones on their pages (a quote found other than once, or whose number cannot be read, stays)."""
    registry = registry or project / "docs" / "quoted-numbers.toml"
    quotes = tomllib.loads(registry.read_text())["quote"]
    cache, problems, pages = {}, [], {}
    for k, q in enumerate(quotes, 1):
        page = project / q["page"]
        text = pages.setdefault(page, page.read_text())
        try:
            want = render(q["template"], [value_of(results_root, s, cache) for s in q["values"]])
        except (OSError, KeyError, IndexError, ValueError, TypeError) as exc:
            problems.append(f"{registry.name} quote {k} ({q['page']}): cannot read its number: {exc!r}")
            continue
        found = pattern(q["template"]).findall(text)
        if len(found) != 1:
            problems.append(f"{q['page']}: quote {k} ({q['template']!r}) found {len(found)} times, expected once")
        elif found[0] != want:
            problems.append(f"{q['page']}: quotes {found[0]!r}, the results say {want!r}")
            if fix:
                text = pages[page] = text.replace(found[0], want)
    if fix:
        for page, text in pages.items():
            if text != page.read_text():
                page.write_text(text)
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=Path("."), help="root the FILE paths are relative to")
    ap.add_argument("--fix", action="store_true", help="rewrite stale quoted numbers from the results")
    args = ap.parse_args(argv)
    problems = check(Path("."), args.results, fix=args.fix)
    for p in problems:
        print(("fixed: " if args.fix else "") + p, file=sys.stderr)
    return 1 if (check(Path("."), args.results) if args.fix else problems) else 0


if __name__ == "__main__":
    sys.exit(main())
