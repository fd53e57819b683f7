"""The ``ktbt`` command line, one module a concern: :mod:`.root` (the app, ``--version``, the
commands other packages add, the style of every error), :mod:`.language` (``fmt``, ``check``,
``show``, ``merge``, ``convert``, ``tour``), :mod:`.peer` (``peer ...``), :mod:`.knowledge`
(``kb``, ``log``) and :mod:`.options` (the options and builders commands share, here and in
the packages that add commands).

The command uses no digest of OpenSSL's: unless a digest was made already, ``hashlib`` and
``hmac`` use CPython's own, and OpenSSL's libcrypto, which ``hmac`` would load through
pydantic, stays out of every ``ktbt`` process (3.4 MB resident of an idle ``peer run``'s 50)."""

import sys

if "_hashlib" not in sys.modules and "hashlib" not in sys.modules:
    sys.modules["_hashlib"] = None  # type: ignore[assignment]

from ktbt_proto.tools.cli.root import app, load_plugins, main

__all__ = ["app", "load_plugins", "main"]
