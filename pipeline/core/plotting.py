"""Shared plotting: deterministic, atomically written multi-page PDFs laid out for a reader.

Same inputs give the same PDF bytes: fixed metadata and creation date, no random ids
(matplotlib honours SOURCE_DATE_EPOCH; we also pass the metadata explicitly), fonts embedded
(Type 42), and the file appears only when complete (temporary file + rename).

Every report opens with one page answering its reader's questions at a glance
(:func:`summary_page`: a typeset table of the headline numbers, the one picture that shows where
the model fails, a caption saying what to see); console-text pages (:func:`text_page`: logs,
long lists, monospace tables beside a paper's) are kept back and written last, as an appendix.
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
A4 = (8.27, 11.69)

STYLE = {
    "figure.figsize": (8.27, 11.69 / 2),  # half an A4 page per figure
    "axes.grid": True,
    "grid.alpha": 0.3,
    "font.size": 9,
    "axes.titlesize": 10,
    "legend.fontsize": 8,
    "savefig.dpi": 150,
    "pdf.compression": 6,
    "pdf.fonttype": 42,           # TrueType fonts, embedded whole: the page reads the same on any viewer
    "svg.hashsalt": "jointcal",
}

#: marks a page of the appendix (its title starts with it); the layout test allows console text there only
APPENDIX = "Appendix"


class ReportPdf:
    """The pages of a report being written: figures in order, console-text pages held for the appendix.

    ``save(pdf, fig)`` adds a figure as the next page; :func:`text_page` adds a page of monospaced
    text to the appendix, written after every figure when the report closes.
    """

    def __init__(self, pages: PdfPages):
        self._pages = pages
        self._appendix = []

    def savefig(self, fig):
        self._pages.savefig(fig)

    def add_appendix(self, title: str, lines, fontsize: float) -> None:
        self._appendix.append((title, list(lines), fontsize))

    def write_appendix(self) -> None:
        for k, (title, lines, fontsize) in enumerate(self._appendix, 1):
            _text_pages(self._pages, f"{APPENDIX} {k}: {title}", lines, fontsize)
        self._appendix = []


@contextlib.contextmanager
def pdf_pages(path, title: str):
    """Yield a :class:`ReportPdf` whose bytes depend only on what is drawn; written atomically, the
    appendix (every :func:`text_page`) last."""
    os.environ.setdefault("SOURCE_DATE_EPOCH", "1577836800")
    meta = {"Title": title, "Author": "jointcal", "Creator": "jointcal", "Producer": "jointcal",
            "CreationDate": FIXED_DATE, "ModDate": FIXED_DATE}
    with plt.rc_context(STYLE), atomic_path(path) as tmp:
        with PdfPages(tmp, metadata=meta) as pages:
            pdf = ReportPdf(pages)
            yield pdf
            pdf.write_appendix()


def save(pdf, fig):
    """Add a figure as a page and close it."""
    pdf.savefig(fig)
    plt.close(fig)


def _wrap_lines(lines, width):
    wrapped = []
    for line in lines:
        indent = len(line) - len(line.lstrip())
        wrapped += textwrap.wrap(line, width, subsequent_indent=" " * (indent + 2), drop_whitespace=False) or [""]
    return wrapped


def _text_chunks(lines, fontsize):
    """The lines of a text page wrapped to the page's width, a list a page."""
    # characters that fit across the page in monospace: 88 % of 8.27 in at 0.602 em a character
    width = int(0.88 * A4[0] * 72 / (0.602 * fontsize))
    rows = int(0.86 * A4[1] * 72 / (1.27 * fontsize))     # lines down the page at matplotlib's spacing (measured)
    wrapped = _wrap_lines(lines, width)
    return [wrapped[i:i + rows] for i in range(0, len(wrapped), rows)] or [[]]


def text_page_count(lines, fontsize=9) -> int:
    """How many pages :func:`text_page` takes for ``lines`` at ``fontsize``."""
    return len(_text_chunks(lines, fontsize))


def _text_pages(pages, title, lines, fontsize):
    chunks = _text_chunks(lines, fontsize)
    for k, chunk in enumerate(chunks):
        fig = plt.figure(figsize=A4)
        t = title if len(chunks) == 1 else f"{title} ({k + 1}/{len(chunks)})"
        fig.text(0.06, 0.965, fit_lines(t, 0.88 * A4[0], 12), fontsize=12, weight="bold", va="top")
        fig.text(0.06, 0.925, "\n".join(chunk), family="monospace", fontsize=fontsize, va="top")
        pages.savefig(fig)
        plt.close(fig)


def text_page(pdf, title: str, lines, fontsize=9):
    """Monospaced text (logs, long lists, tables beside a paper's): a page of the appendix, written
    last; continued on more pages when long."""
    if isinstance(pdf, ReportPdf):
        pdf.add_appendix(title, lines, fontsize)
    else:
        _text_pages(pdf, title, lines, fontsize)


# ------------------------------------------------------------------------------ layout helpers
def fit_lines(text: str, width_in: float, fontsize: float, lines: int = 2, em: float = 0.55) -> str:
    """:func:`fit_text` of ``text`` on at most ``lines`` lines: when it takes more, its middle is left
    out ("...") until it fits, so a long folder name in a title keeps its start and its end and the
    title stays clear of what is drawn below it."""
    out = fit_text(text, width_in, fontsize, em)
    keep = len(text)
    while out.count("\n") >= lines and keep > 10:
        keep -= max(1, keep // 20)
        head = keep // 2
        out = fit_text(text[:head] + "..." + text[len(text) - (keep - head):], width_in, fontsize, em)
    return out


def fit_text(text: str, width_in: float, fontsize: float, em: float = 0.55) -> str:
    """``text`` wrapped on words to lines that fit ``width_in`` inches at ``fontsize`` points
    (``em``: a proportional font's mean character width in em)."""
    chars = max(10, int(width_in * 72 / (em * fontsize)))
    return "\n".join(textwrap.fill(part, chars, break_on_hyphens=False) for part in str(text).split("\n"))


def title_on_page(fig, ax, text: str, fontsize: float, rect=(0, 0, 1, 1)) -> None:
    """After ``fig.tight_layout(rect=rect)``: when ``ax``'s title (``text``, centred over the axes) reaches
    past the figure's edges, wrap it to the widest line that fits centred there and lay the figure out
    again; a title that fits is left as it is."""
    renderer = fig.canvas.get_renderer()
    box, width_px = ax.title.get_window_extent(renderer), fig.bbox.width
    if box.x0 >= 0 and box.x1 <= width_px:
        return
    pos = ax.get_position()
    centre = (pos.x0 + pos.x1) / 2
    fits_in = 2 * min(centre, 1 - centre) * fig.get_figwidth() * 0.95
    ax.set_title(fit_text(" ".join(text.split("\n")), fits_in, fontsize), fontsize=fontsize)
    fig.tight_layout(rect=rect)


def caption(fig, text: str, y: float = 0.012, fontsize: float = 8.5) -> None:
    """A caption sentence at the foot of a figure: what to see."""
    w = fig.get_figwidth()
    fig.text(0.06, y, fit_text(text, 0.88 * w, fontsize), fontsize=fontsize, va="bottom", ha="left",
             style="italic", color="0.15")


def table(ax, header, rows, fontsize=8.0, align=None, bold_rows=()):
    """A typeset table filling ``ax``: aligned columns (text left, numbers right), rules above and under
    the header and at the foot, no wrapped lines.

    Parameters
    ----------
    ax : Axes (its frame is turned off)
    header : list of str, one a column (units in the header, e.g. ``"RMS (mm)"``; ``\\n`` breaks it)
    rows : list of lists of str, each as long as ``header``
    align : list of ``"l"``/``"r"``/``"c"``, one a column; default first left, others right
    bold_rows : indices of rows set bold, their first cell spanning the row (a section's heading)
    """
    ax.set_axis_off()
    n = len(header)
    align = align or (["l"] + ["r"] * (n - 1))
    loc = {"l": "left", "r": "right", "c": "center"}
    body = [list(r) for k, r in enumerate(rows) if k not in bold_rows]
    # column widths: the widest cell as drawn (a heading row spans the table: not counted), plus a gap
    renderer = ax.figure.canvas.get_renderer()

    def width(text, bold, size):
        t = ax.figure.text(0, 0, text, fontsize=size, weight="bold" if bold else "normal")
        w = t.get_window_extent(renderer).width
        t.remove()
        return w

    def widths_at(size):
        gap = 1.2 * size * ax.figure.dpi / 72.0
        return [max([width(str(header[j]), True, size)] + [width(str(r[j]), False, size) for r in body]) + gap
                for j in range(n)]

    avail = ax.get_window_extent(renderer).width
    widths = widths_at(fontsize)
    if sum(widths) > avail:          # too wide for the page at this size: a smaller font, never a wrapped line
        fontsize = round(fontsize * avail / sum(widths) * 0.98, 2)
        widths = widths_at(fontsize)
    total = float(sum(widths))
    x0 = [sum(widths[:j]) / total for j in range(n)]
    x1 = [sum(widths[:j + 1]) / total for j in range(n)]
    head_lines = max(str(h).count("\n") + 1 for h in header)
    units = head_lines + len(rows)
    h = 1.0 / max(units, 1)
    y_head = 1.0 - head_lines * h
    for j, c in enumerate(header):
        a = align[j]
        x = x0[j] + 0.004 if a == "l" else x1[j] - 0.008 if a == "r" else (x0[j] + x1[j]) / 2
        ax.text(x, y_head + 0.25 * h, str(c), transform=ax.transAxes, ha=loc[a], va="bottom", fontsize=fontsize,
                weight="bold", multialignment=loc[a], linespacing=1.1)
    for i, row in enumerate(rows):
        y = y_head - (i + 0.5) * h
        if i in bold_rows:
            ax.text(0.004, y, str(row[0]), transform=ax.transAxes, ha="left", va="center", fontsize=fontsize,
                    weight="bold")
            continue
        for j, c in enumerate(row):
            a = align[j]
            x = x0[j] + 0.004 if a == "l" else x1[j] - 0.008 if a == "r" else (x0[j] + x1[j]) / 2
            ax.text(x, y, str(c), transform=ax.transAxes, ha=loc[a], va="center", fontsize=fontsize)
    for yy, lw in ((1.0, 0.9), (y_head, 0.6), (0.0, 0.9)):
        ax.plot([0, 1], [yy, yy], color="k", lw=lw, transform=ax.transAxes, clip_on=False)


def summary_page(pdf, title: str, subtitle: str, header, rows, draw, caption_text: str, notes=(),
                 align=None, bold_rows=(), table_fontsize=8.0):
    """The report's first page: the headline numbers as a typeset table, the one picture that shows
    where the model fails, and a caption saying what to see.

    Parameters
    ----------
    title, subtitle : str (what the report is about; the data it was drawn from)
    header, rows : the table (see :func:`table`)
    draw : callable ``draw(fig, rect)`` drawing the picture in ``rect = (left, bottom, width, height)``
        (figure fractions), e.g. with ``fig.add_gridspec(...)`` or ``fig.add_axes(rect)``
    caption_text : str, one or two sentences under the picture
    notes : short plain-words lines under the table (verdicts), proportional font
    """
    fig = plt.figure(figsize=A4)
    W = 0.88 * A4[0]
    fig.text(0.06, 0.975, fit_text(title, W, 13), fontsize=13, weight="bold", va="top")
    sub = fit_text(subtitle, W, 8.5)
    fig.text(0.06, 0.945, sub, fontsize=8.5, va="top", color="0.25")
    top = 0.945 - 0.0135 * (sub.count("\n") + 1) - 0.012
    row_h = 0.0125 * table_fontsize / 8.0 * 1.45
    th = row_h * (len(rows) + max(str(h).count("\n") + 1 for h in header))
    ax = fig.add_axes((0.06, top - th, 0.88, th))
    table(ax, header, rows, fontsize=table_fontsize, align=align, bold_rows=bold_rows)
    y = top - th - 0.012
    for note in notes:
        t = fit_text(note, W, 8.5)
        fig.text(0.06, y, t, fontsize=8.5, va="top")
        y -= 0.0135 * (t.count("\n") + 1) + 0.004
    cap = fit_text(caption_text, W, 8.5)
    cap_h = 0.0135 * (cap.count("\n") + 1) + 0.02
    bottom = cap_h + 0.045
    draw(fig, (0.1, bottom, 0.84, y - 0.055 - bottom))
    fig.text(0.06, 0.012, cap, fontsize=8.5, va="bottom", style="italic", color="0.15")
    save(pdf, fig)
