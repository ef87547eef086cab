"""The one error type users see: bad input, located by file, line and column."""

from __future__ import annotations

import re
import tomllib


class InputError(Exception):
    """Bad input. Printed as one line ``file:line:column: message``; exit status 2.

    Parameters
    ----------
    path : str
        File the problem is in.
    message : str
        What is wrong and what was expected.
    line : int, optional
        1-based line number in the file (the header is line 1 of a CSV).
    column : str or int, optional
        Column name (CSV) or 1-based character column (TOML).
    """

    def __init__(self, path, message, line=None, column=None):
        self.path = str(path)
        self.message = message
        self.line = line
        self.column = column
        super().__init__(self.one_line())

    def one_line(self) -> str:
        line = "-" if self.line is None else str(self.line)
        column = "-" if self.column is None else str(self.column)
        text = " ".join(str(self.message).split())
        return f"{self.path}:{line}:{column}: {text}"


def parse_toml(text: str, path) -> dict:
    """Parse TOML text; a syntax error becomes an InputError with its line and column."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+), column (\d+)", str(exc))
        line, col = (int(m.group(1)), int(m.group(2))) if m else (None, None)
        raise InputError(path, f"not valid TOML: {str(exc).split(' (at')[0]}", line, col) from None
