"""The ``ktbt`` command line, one module a concern: :mod:`.root` (the app, ``--version``, the
commands other packages add, the style of every error), :mod:`.language` (``fmt``, ``check``,
``show``, ``merge``, ``convert``, ``tour``), :mod:`.peer` (``peer ...``), :mod:`.knowledge`
(``kb``, ``log``) and :mod:`.options` (the options and builders commands share, here and in
the packages that add commands).

The command uses no digest of OpenSSL's: unless a digest was made already, or this Python was
built without its own digests (then OpenSSL's are hashlib's only ones), ``hashlib`` and
``hmac`` use CPython's own, and OpenSSL's libcrypto, which ``hmac`` would load through
pydantic, stays out of every ``ktbt`` process (3.4 MB resident of an idle ``peer run``'s 50)."""

import sys
from importlib.util import find_spec

if (
    "_hashlib" not in sys.modules
    and "hashlib" not in sys.modules
    # CPython's own digests, which a build may leave out (then hashlib has only OpenSSL's)
    and all(
        find_spec(name) is not None
        for name in (
            ("_md5", "_sha1", "_sha2")
            if sys.version_info >= (3, 12)
            else ("_md5", "_sha1", "_sha256", "_sha512")
        )
    )
):
    sys.modules["_hashlib"] = None  # type: ignore[assignment]

from ktbt_proto.tools.cli.root import app, load_plugins, main

__all__ = ["app", "load_plugins", "main"]
