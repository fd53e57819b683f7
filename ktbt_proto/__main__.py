"""``python -m ktbt_proto`` is the ``ktbt`` command."""

from .cli import main

main()
