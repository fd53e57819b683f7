"""``python -m ktbt_proto`` is the ``ktbt`` command."""

from ktbt_proto.tools.cli import main

main()
