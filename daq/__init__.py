"""gvtlink DAQ: the service at the root (recording and replay), the offline studies (``studies``), the CLI (``cli``).

Importing it imports :mod:`analysis` first, whose ``__init__`` sets the one-BLAS-thread default
(docs/decisions.md D19) before anything loads numpy.
"""

import analysis  # noqa: F401 - the BLAS thread default, before numpy
