"""``python -m daq.cli``: the same as the ``gvt`` console script."""

from daq.cli import main

main()
