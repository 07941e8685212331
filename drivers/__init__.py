"""gvtlink drivers: the shared SampleBlock record (``drivers/blocks.py``), the Driver interface and the transports.

Importing it imports :mod:`analysis` first, whose ``__init__`` sets the one-BLAS-thread default
(docs/decisions.md D19) before anything loads numpy; the simulated device builds on ``analysis.model``.
"""

import analysis  # noqa: F401 - the BLAS thread default, before numpy
