"""The ``ktbt`` command line, one module a concern: :mod:`.root` (the app, ``--version``, the
commands other packages add, the style of every error), :mod:`.language` (``fmt``, ``check``,
``show``, ``merge``, ``convert``, ``tour``), :mod:`.peer` (``peer ...``), :mod:`.knowledge`
(``kb``, ``log``) and :mod:`.options` (the options and builders commands share, here and in
the packages that add commands)."""

from ktbt_proto.tools.cli.root import app, load_plugins, main

__all__ = ["app", "load_plugins", "main"]
