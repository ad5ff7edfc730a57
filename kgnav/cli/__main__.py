"""``python -m kgnav.cli``: the ``kgnav`` command."""

from kgnav.cli import main

main()
