"""``python -m beambench``: the same as the ``beambench`` command."""

from beambench.cli import main

main()
