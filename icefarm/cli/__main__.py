"""``python -m icefarm.cli``: the ``icefarm`` command."""

from .main import main

main()
