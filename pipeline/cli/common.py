"""What the commands share: reading the stages' files, locating spec errors, loading specs.

The commands import the library (and numpy, pandas) inside their bodies, not at the top of
their modules: the whole library pulls numpy, pandas, scipy, pinocchio, matplotlib and dask,
slow to import (docs/speed.md "Measurements behind the code"), which ``jointcal --help`` and
every command would otherwise pay whatever it uses. Each command imports what
it runs, which is also what ``make`` reads to know a stage's code (``mk/deps.py``).
"""

from __future__ import annotations

from pathlib import Path

import click

from ..core.errors import InputError


class HiddenOption(click.Option):
    """``--hidden`` of a simulator: its help's ``{choices}`` lists the effects the simulator can hide,
    from the registry, through ``choices_help`` (a function, called only when help is shown, so
    that start-up stays free of the library)."""

    def __init__(self, *args, choices_help=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.choices_help = choices_help

    def get_help_record(self, ctx):
        if self.choices_help is not None and self.help:
            self.help = self.help.replace("{choices}", self.choices_help())
        return super().get_help_record(ctx)


def fail_spec(spec_path, message, pattern=r"^\s*(orders|n_max)\s*="):
    """Raise an InputError at the first line of the spec matching ``pattern``."""
    from ..core.spec import _locate

    try:
        text = Path(spec_path).read_text(encoding="utf-8")
        line, col = _locate(text, pattern)
    except OSError:
        line, col = None, None
    raise InputError(spec_path, message, line, col)


def read_json(path, hint: str = "run the stage that makes it first, or `make all`"):
    from ..core.files import read_json_input

    return read_json_input(path, hint)


def read_interim(path):
    from ..core.files import read_parquet_input

    return read_parquet_input(path)


def load_spec(path):
    """A spec of either kind, read with both domains' vocabularies (so that a spec of the other
    kind is refused by its ``kind``, not by an effect name): the encoder and robot packages are
    imported first, and each registers its effects in its ``__init__``."""
    from .. import encoder, robot  # noqa: F401  (loaded for their effects: see above)
    from ..core.spec import load_spec as load

    return load(path)
