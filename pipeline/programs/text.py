"""Program text: bytes kept as they are, numbers found and rewritten in their own spelling.

A program is read as bytes and decoded as Latin-1, one character per byte, so that any encoding
(a controller's Windows code page, UTF-8, Shift-JIS) and any line ending (CRLF) survives a round
trip byte for byte: only ASCII digits, signs and points are ever replaced. A UTF-8 byte-order mark
is kept and not read; a file with a UTF-16 byte-order mark is decoded as UTF-16 and written back so. A rewritten number keeps its
number of decimals, its explicit ``+``, a missing leading zero (``.582``, ``-.593``); a number
whose rounded new value spells the same is not touched at all.
"""

from __future__ import annotations

import bisect
import re
from dataclasses import dataclass

from ..core.errors import InputError
from ..core.files import read_bytes_input

#: a number as the four languages spell it (``12``, ``-3.5``, ``.582``, ``9E+09``, ``1.5e-3``)
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
NUMBER_RE = re.compile(NUMBER)


#: byte-order marks a controller accepts at the start of a program file, and the codec each names
BOMS = ((b"\xef\xbb\xbf", "latin-1"), (b"\xff\xfe", "utf-16-le"), (b"\xfe\xff", "utf-16-be"))


@dataclass
class Source:
    """One program file: its path as given and its text.

    ``text`` is what the readers see: the bytes decoded one character per byte (Latin-1) or, for a
    file that starts with a UTF-16 byte-order mark, as UTF-16, with the byte-order mark blanked to
    spaces (offsets stay). :meth:`encode` gives the bytes of a (rewritten) text: the mark and the
    codec as read, so an unchanged text is the file's bytes exactly. ``writable`` is False for a file
    read for its data only (the controller's ``$config.dat``), which the filter never writes.
    """

    path: str
    text: str
    encoding: str = "latin-1"
    bom: str = ""
    writable: bool = True
    rel: str = ""          # the path inside the --program folder it was read from ("": its own name)

    def line_of(self, pos: int) -> int:
        """1-based line of a character position."""
        if not hasattr(self, "_starts"):
            self._starts = [m.end() for m in re.finditer("\n", self.text)]
        return bisect.bisect_right(self._starts, pos) + 1

    def encode(self, text: str) -> bytes:
        """Bytes of ``text`` (this file's text with numbers replaced): byte-order mark and codec as read."""
        return (self.bom + text[len(self.bom):]).encode(self.encoding)


def decode_program(data: bytes, path: str = "<program>") -> Source:
    """A program file's bytes as a :class:`Source` (see there); InputError for a file that is not text."""
    for mark, codec in BOMS:
        if data.startswith(mark):
            if codec == "latin-1":
                bom = mark.decode("latin-1")
                text = data.decode("latin-1")
            else:
                try:
                    text = data.decode(codec)
                except UnicodeDecodeError as exc:
                    raise InputError(path, f"not a program: a UTF-16 byte-order mark, but byte {exc.start} is not "
                                     "UTF-16 text", 1, None) from None
                bom = text[0]
            return Source(str(path), " " * len(bom) + text[len(bom):], codec, bom)
    if b"\x00" in data:
        at = data.index(b"\x00")
        raise InputError(path, "not a program: a binary file (NUL bytes; a program is text)",
                         data.count(b"\n", 0, at) + 1, at - (data.rfind(b"\n", 0, at) + 1) + 1)
    return Source(str(path), data.decode("latin-1"))


def read_source(path, writable: bool = True) -> Source:
    """Read a program file byte for byte (InputError when it is missing or not text)."""
    data = read_bytes_input(path, "program file", "a program file, not a folder")
    src = decode_program(data, str(path))
    src.writable = writable
    return src


@dataclass
class Number:
    """A number in a program: file index, span [start, end) and its text."""

    file: int
    start: int
    end: int
    text: str
    lead: int = 0          # spaces before the number inside the span (FANUC: right-aligned fields)

    @property
    def value(self) -> float:
        return float(self.text)

    def respell(self, value: float) -> str | None:
        """The span's new text for ``value`` (None when it would spell the same number)."""
        s = spell(value, self.text)
        if float(s) == self.value:
            return None
        if self.lead:
            width = self.lead + len(self.text)
            s = s.rjust(width) if len(s) < width else " " + s
        return s

    @property
    def decimals(self) -> int:
        mant = re.split(r"[eE]", self.text.strip())[0]
        return len(mant.split(".")[1]) if "." in mant else 0


def spell(value: float, like: str) -> str:
    """``value`` written as ``like`` is: same decimals, explicit ``+``, leading zero or not, exponent.

    The rounded value is written; a negative zero is written as zero.
    """
    m = re.fullmatch(r"([-+]?)(\d*)(\.?)(\d*)([eE][-+]?\d+)?", like)
    if not m:
        raise ValueError(f"not a number: {like!r}")
    sign, intpart, point, frac, expo = m.groups()
    dec = len(frac)
    if expo:
        e = int(expo[1:])
        mant = value / 10.0 ** e
        body = f"{abs(mant):.{dec}f}"
        if float(body) == 0.0:
            return like
        neg = mant < 0
        out = body + expo
    else:
        body = f"{abs(value):.{dec}f}"
        neg = value < 0 and float(body) != 0.0
        if not point:
            body = f"{abs(round(value)):d}"
            neg = round(value) < 0
        elif dec == 0:
            body = f"{abs(round(value)):d}."
        out = body
    if not intpart and out.startswith("0."):
        out = out[1:]
    if neg:
        return "-" + out
    return ("+" if sign == "+" else "") + out


def rewrite(sources: list[Source], changes: dict[tuple[int, int, int], str]) -> list[str]:
    """Texts of the files with the numbers at ``(file, start, end)`` replaced (nothing else touched)."""
    out = []
    for i, s in enumerate(sources):
        pieces, at = [], 0
        for (f, a, b), new in sorted((k, v) for k, v in changes.items() if k[0] == i):
            pieces += [s.text[at:a], new]
            at = b
        pieces.append(s.text[at:])
        out.append("".join(pieces))
    return out


def strip_comment(line: str, marker: str) -> str:
    """``line`` without its comment (``marker`` outside double quotes)."""
    if marker not in line:
        return line
    inside = False
    for k, ch in enumerate(line):
        if ch == '"':
            inside = not inside
        elif not inside and line.startswith(marker, k):
            return line[:k]
    return line


def split_top(s: str, sep: str = ",") -> list[tuple[int, str]]:
    """Split ``s`` at ``sep`` outside brackets, parentheses, braces and quotes: (offset, part) pairs."""
    parts, depth, start, inside = [], 0, 0, False
    for k, ch in enumerate(s):
        if ch == '"':
            inside = not inside
        elif inside:
            continue
        elif ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == sep and depth == 0:
            parts.append((start, s[start:k]))
            start = k + 1
    parts.append((start, s[start:]))
    return parts


def balanced(s: str) -> bool:
    """Brackets, parentheses and braces balanced and properly nested (outside double quotes)."""
    stack, inside = [], False
    pairs = {")": "(", "]": "[", "}": "{"}
    for ch in s:
        if ch == '"':
            inside = not inside
        elif inside:
            continue
        elif ch in "([{":
            stack.append(ch)
        elif ch in pairs:
            if not stack or stack.pop() != pairs[ch]:
                return False
    return not stack and not inside
