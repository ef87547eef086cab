"""Shared plotting: deterministic, atomically written multi-page PDFs.

Same inputs give the same PDF bytes: fixed metadata and creation date, no random ids
(matplotlib honours SOURCE_DATE_EPOCH; we also pass the metadata explicitly), and the
file appears only when complete (temporary file + rename).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.backends.backend_pdf import PdfPages  # noqa: E402

from .files import atomic_path  # noqa: E402

FIXED_DATE = dt.datetime(2020, 1, 1, tzinfo=dt.timezone.utc)

STYLE = {
    "figure.figsize": (8.27, 11.69 / 2),  # half an A4 page per figure
    "axes.grid": True,
    "grid.alpha": 0.3,
    "font.size": 9,
    "axes.titlesize": 10,
    "legend.fontsize": 8,
    "savefig.dpi": 150,
    "pdf.compression": 6,
    "svg.hashsalt": "jointcal",
}


@contextlib.contextmanager
def pdf_pages(path, title: str):
    """Yield a PdfPages whose bytes depend only on what is drawn; written atomically."""
    os.environ.setdefault("SOURCE_DATE_EPOCH", "1577836800")
    meta = {"Title": title, "Author": "jointcal", "Creator": "jointcal", "Producer": "jointcal",
            "CreationDate": FIXED_DATE, "ModDate": FIXED_DATE}
    with plt.rc_context(STYLE), atomic_path(path) as tmp:
        with PdfPages(tmp, metadata=meta) as pdf:
            yield pdf


def save(pdf, fig):
    """Add a figure as a page and close it."""
    pdf.savefig(fig)
    plt.close(fig)


def text_page(pdf, title: str, lines, fontsize=9):
    """A page of monospaced text (tables of numbers beside the paper's)."""
    # characters that fit across the page in monospace: 88 % of 8.27 in at 0.602 em a character
    width = int(0.88 * 8.27 * 72 / (0.602 * fontsize))
    wrapped = []
    for line in lines:
        indent = len(line) - len(line.lstrip())
        wrapped += textwrap.wrap(line, width, subsequent_indent=" " * (indent + 2), drop_whitespace=False) or [""]
    fig = plt.figure(figsize=(8.27, 11.69))
    fig.text(0.06, 0.96, title, fontsize=13, weight="bold", va="top")
    fig.text(0.06, 0.92, "\n".join(wrapped), family="monospace", fontsize=fontsize, va="top")
    save(pdf, fig)
