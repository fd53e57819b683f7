"""Files: the package's own data, bounded reads, and the one durable write.

Packaged data (the grammar, the examples) is found one way, :func:`packaged`, so a wheel and a
source checkout read the same files: the grammar lives inside the package, the examples at the
top of a checkout (``examples/``, beside ``spec/`` and ``tests/``, where people look for them),
and the wheel carries a copy of them inside the package. A file someone
else may have written (a key, a trust store, a knowledge base, a tree) is read one way,
:func:`read_bounded`, so a path such as ``/dev/zero`` is refused, not read until memory runs out.

Durable file replacement is the one way the project writes a file that must survive a crash.

A knowledge base, a formatted source file, a trial's results and a fleet's records are all
replaced the same way (spec/protocol.md section 5, persistence): the new contents go to a
temporary file in the same folder, which is flushed to disk and renamed over the old one, and the
folder itself is flushed so that the rename survives a power loss. A crash at any point leaves
either the old file or the new one, never a mixture; a temporary file left by a crash is named
``.<name>.<pid>.<random>.tmp`` beside its target, so its owner can find and remove it.
"""

from __future__ import annotations

import contextlib
import glob
import importlib.resources
import os
import re
import secrets
from collections.abc import Iterator
from pathlib import Path

TOP_LEVEL = frozenset({"examples"})
"""Data that sits at the top of a source checkout, beside the package, and inside the package
only in a wheel (which maps the folder in)."""


def packaged(*parts: str) -> Path:
    """A file or folder shipped with the package: ``packaged("examples", "sar_control.sbt")``,
    ``packaged("grammar", "stringbt.lark")``. The package is installed as files (a wheel or a
    source checkout), so the resource is a real path other processes can be handed.

    The examples are found inside the package (a wheel carries them there) or else at the top
    of the checkout the package is imported from (an editable install or a clone), the folder
    that holds ``pyproject.toml``; a name outside :data:`TOP_LEVEL` is always the package's own.
    """
    package = Path(str(importlib.resources.files("ktbt_proto")))
    inside = package.joinpath(*parts)
    if parts and parts[0] in TOP_LEVEL and not inside.exists():
        checkout = package.parent
        if (checkout / "pyproject.toml").is_file() and (checkout / parts[0]).is_dir():
            return checkout.joinpath(*parts)
    return inside


class TooLarge(ValueError):
    """A file larger than its reader accepts (``read_bounded``)."""


def read_at_most(path: str | os.PathLike[str], limit: int) -> bytes:
    """The first ``limit + 1`` bytes of ``path`` at most: enough for a reader with its own
    positioned error (the stringBT parser's size limit) to refuse a larger file without ever
    holding all of it; raises ``OSError`` as ``open`` does."""
    with open(path, "rb") as f:
        return f.read(limit + 1)


def read_bounded(path: str | os.PathLike[str], limit: int) -> bytes:
    """At most ``limit`` bytes of ``path``; raises :class:`TooLarge` for a larger file (only
    ``limit + 1`` bytes are ever read) and ``OSError`` as ``open`` does."""
    data = read_at_most(path, limit)
    if len(data) > limit:
        raise TooLarge(f"{path} is larger than {limit} bytes")
    return data


def temporary_name(final: Path) -> Path:
    """A fresh temporary name beside ``final`` (the pattern ``.<name>.*.tmp``)."""
    return final.with_name(f".{final.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")


def temporaries(path: str | Path) -> list[Path]:
    """The temporary files a replace of ``path`` killed midway may have left (a symlink is
    followed, as :func:`replacing` follows it), oldest name first."""
    final = Path(os.path.realpath(path))
    # ``.<name>.<pid>[.<hex>].tmp`` only: ``.kb.json.bak.1.ab12cd34.tmp`` is kb.json.bak's.
    own = re.compile(rf"\.{re.escape(final.name)}\.[0-9]+(?:\.[0-9a-f]+)?\.tmp")
    found = final.parent.glob(f".{glob.escape(final.name)}.*.tmp")
    return sorted(p for p in found if own.fullmatch(p.name))


def fsync_folder(folder: Path) -> None:
    """Flush a folder's entries (a rename in it) to disk."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def replacing(path: str | Path, *, keep_mode: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write the new contents to; on a clean exit it is flushed and
    renamed over ``path``, on an exception it is removed and ``path`` is untouched.

    A symlink is written through (its target changes, the link stays). ``keep_mode`` keeps the
    permissions of the file being replaced; otherwise a new file gets the mode ``open`` gives.
    """
    final = Path(os.path.realpath(path))
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(final)
    os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        if keep_mode:
            with contextlib.suppress(OSError):
                os.chmod(tmp, os.stat(final).st_mode & 0o7777)
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_folder(final.parent)


def write_atomic(path: str | Path, data: str | bytes, *, keep_mode: bool = False) -> None:
    """Replace ``path``'s contents with ``data`` (text is written as UTF-8 with ``\\n`` line
    ends) so that a crash leaves either the old or the new file."""
    with replacing(path, keep_mode=keep_mode) as tmp:
        if isinstance(data, str):
            with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
                fh.write(data)
        else:
            tmp.write_bytes(data)
