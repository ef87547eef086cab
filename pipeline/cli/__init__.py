"""The ``jointcal`` command: one thin click subcommand per stage (:mod:`pipeline.cli.main`).

Commands read files, call the library's pure functions and write results atomically; the
library never calls the command line. Bad input ends with exit status 2 and one line
``file:line:column: message``.
"""

import os

# The linear algebra here is small (hundreds of parameters at most): one BLAS thread is
# faster and steadier than OpenBLAS's spinning pool (measured: up to 100x on two cores).
# Set before numpy is first imported; the user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from .main import cli, main  # noqa: E402  (after the thread settings above)

__all__ = ["cli", "main"]
