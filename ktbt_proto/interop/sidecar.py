"""Learning for a BehaviorTree.CPP program: each learned item as a BT.CPP document in a folder.

A running BT.CPP tree cannot be edited, so a KT-BT agent beside the program learns for it and
:class:`LearnedExport` mirrors what the agent has learned into a folder (spec/stringbt.md,
section 12.1): one file per item, ``NNNNNN-<placeholder>-<digest>.xml``, whose one
``<BehaviorTree ID="ktbt-<placeholder>-<digest>">`` is the item ``Sequence(conditions,
subtree)``. ``NNNNNN`` (six digits or more) numbers the items in the order they were learned,
so the program places them in that order; the item's digest (``items.item_digest``: its
condition sequence and subtree) beside its placeholder names it, so an item learned again with
another subtree gets a new file. A file is
replaced whole (``ktbt_proto.files``), so the program never reads half of one, and it is removed
at the first sync after the agent forgets its item. An item BT.CPP could not load (a node named
like one of its built-ins) is refused with its reason, logged once and not written. The export
only observes the agent's knowledge base (:meth:`LearnedExport.sync`, after each tick): it
changes nothing in the agent.

A tree's ID may be given per condition sequence (``tree_ids``, spec/stringbt.md section 12.2)
instead of the derived one. Such an item's file is ``<ID>.xml``, a path that stays the same
while the item is learned again with another subtree (the new document replaces the old one in
one rename, never a moment without the file), so a program can name it: Nav2 on Jazzy includes
it in its navigation tree (``<include path=...>``, then ``<SubTree ID=...>``; section 12.3),
newer Nav2 picks it by ID from its ``bt_search_directories``. Its second line, a comment naming
the item, tells a restarted export its own file from the folder's other files. The folder may
be one of Nav2's ``bt_search_directories``, beside the trees Nav2 already reads: Nav2 registers
every ``.xml`` file there and builds the tree a ``NavigateToPose`` goal names by its ID, so each
file is a whole BT.CPP document with its ``main_tree_to_execute``, and an ID another file of the
folder already holds is refused (Nav2 would skip one of the two files), as is an ``<ID>.xml``
that is another file of the folder: at the start, one clear error; later, the item is refused.

A BT.CPP program teaches the same way round: :func:`read_skills` reads its skills from one
document holding one ``<BehaviorTree>`` per item, in the shape :class:`LearnedExport` writes (the
item ``Sequence(conditions, subtree)`` as the tree's root; a ``ktbt-<placeholder>-<digest>`` ID
names its placeholder), so what one robot exported another can serve (``ktbt peer serve
--knowledge skills.xml``). A tree with ``k:`` placeholders (what ``ktbt convert`` makes of a
``.sbt`` knowledge file) gives the items in its placeholders.
"""

from __future__ import annotations

import logging
import os
import re
import tempfile
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.knowledge import Knowledge, KnowledgeBase, remove_stale_temporaries
from ktbt_proto.files import fsync_folder, read_at_most, write_atomic
from ktbt_proto.interop.btcpp import (
    BUILTINS,
    btcpp_name,
    document_tree_ids,
    to_xml,
    trees_from_xml,
)
from ktbt_proto.items import item_digest, read_sequence, sequence_key, split_item
from ktbt_proto.syntax import NAME_PATTERN, NAME_RE
from ktbt_proto.tree import Action, Condition, Placeholder, walk

__all__ = ["LearnedExport", "read_skills", "tree_id"]

log = logging.getLogger(__name__)

_FILE = re.compile(
    rf"(?P<number>[0-9]{{6,}})-(?P<slot>{NAME_PATTERN})-(?P<digest>[0-9a-f]{{16}})\.xml"
)
_TEMPORARY = re.compile(r"\.(?P<name>.+)\.[0-9]+\.[0-9a-f]+\.tmp")


_MARK = "<!-- ktbt learned item {slot} {digest}: written, replaced and removed by its export -->"
_MARKED = re.compile(
    rf"<\?xml[^\n]*\n<!-- ktbt learned item (?P<slot>{NAME_PATTERN}) (?P<digest>[0-9a-f]{{16}}):"
)
"""The comment on the second line of an ``<ID>.xml`` file the export wrote: the item it holds."""

_TREE_ID = re.compile(r"ktbt-(?P<slot>[A-Za-z0-9_-]+)-[0-9a-f]{16}")
_GIVEN_ID = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*")
"""A tree ID given for Nav2: no dot, so it never ends in ``.xml`` (Nav2 takes such a name for a
file), and never ``ktbt-...``, the derived IDs' prefix."""


def tree_id(item: Knowledge, given: Mapping[str, str] | None = None) -> str:
    """The ID of the item's ``<BehaviorTree>``: the one ``given`` for its condition sequence
    (by key), else ``ktbt-<placeholder>-<digest>``, a function of the item alone (spec/
    stringbt.md sections 12.1 and 12.2)."""
    if given and item.key in given:
        return given[item.key]
    return f"ktbt-{btcpp_name(item.segment)}-{item_digest(item.key, item.subtree)}"


def tree_ids(
    given: Iterable[str], read: Callable[[str], tuple[Condition, ...]] = read_sequence
) -> dict[str, str]:
    """``ID=CONDITIONS`` texts (``ktbt peer run --tree-id``, the ROS node's ``tree_ids``) as
    :class:`LearnedExport`'s ``tree_ids``, by sequence key (section 12.2). ``read`` reads the
    conditions (raising ``StringBTError``); a text without ``=`` or naming one sequence twice
    raises ``ValueError`` saying so."""
    ids: dict[str, str] = {}
    for text in given:
        ident, equals, conditions = text.partition("=")
        if not equals or not conditions.strip():
            raise ValueError(f"{text!r}: write ID=CONDITIONS, e.g. 'OpenDoor=DoorClosed'")
        key = sequence_key(read(conditions))
        if ids.setdefault(key, ident.strip()) != ident.strip():
            raise ValueError(f"two IDs for {conditions.strip()!r}")
    return ids


def _check_given(tree_ids: Mapping[str, str]) -> None:
    seen: dict[str, str] = {}
    for key, ident in tree_ids.items():
        if not _GIVEN_ID.fullmatch(ident) or ident.startswith("ktbt-"):
            raise ValueError(
                f"tree ID {ident!r}: a letter or _, then letters, digits, _ or -, "
                "not starting with 'ktbt-'"
            )
        if ident in BUILTINS:
            raise ValueError(f"tree ID {ident!r} is a BT.CPP built-in node's name")
        if ident in seen:
            raise ValueError(f"tree ID {ident!r} is given to two sequences")
        seen[ident] = key


def read_skills(data: str | bytes, slot: str = "prior") -> KnowledgeBase:
    """The knowledge items of a BT.CPP document (spec/stringbt.md section 12.1): each
    ``<BehaviorTree>`` is an item (its root ``Sequence(conditions, subtree)``, in the
    placeholder its ``ktbt-<placeholder>-<digest>`` ID names, else ``slot``) or a tree whose
    ``k:`` placeholders hold items. Raises a :class:`StringBTError` for a document that does
    not read, ``ValueError`` naming a tree that is neither."""
    kb = KnowledgeBase()
    for ident, tree in trees_from_xml(data).items():
        if any(isinstance(node, Placeholder) for node, _ in tree.walk()):
            for item in KnowledgeBase.from_tree(tree):
                kb.add(item)
            continue
        split = split_item(tree.root)
        if split is None:
            raise ValueError(
                f"<BehaviorTree ID={ident!r}> is not a skill: its root must be a "
                "ReactiveSequence of its conditions, then its actions"
            )
        named = _TREE_ID.fullmatch(ident)
        segment = named["slot"].replace("-", ".") if named is not None else slot
        kb.add(Knowledge(split[0], split[1], segment))
    return kb


class LearnedExport:
    """Keeps ``folder`` holding exactly one BT.CPP file per learned item.

    Files of this export already in the folder (a previous run's: the numbered ones, and the
    ``<ID>.xml`` ones its comment marks) are adopted when their item is still known, and
    removed at the first :meth:`sync` otherwise; the temporary files a write killed midway left
    are removed at once. Other files are left alone. A file that cannot be written or removed
    is logged and tried again at the next sync, with the number it was given, never raised
    into the agent's loop.
    """

    def __init__(
        self, folder: str | os.PathLike[str], tree_ids: Mapping[str, str] | None = None
    ) -> None:
        """Raises ``OSError`` (naming the folder) for a folder that cannot be made or written
        into, ``ValueError`` for a ``tree_ids`` ID (by condition sequence key) that is not a
        usable name, is given twice, is held by another file of the folder or whose
        ``<ID>.xml`` is another file of the folder."""
        self.folder = Path(folder)
        _usable(self.folder)
        self.tree_ids = dict(tree_ids or {})
        _check_given(self.tree_ids)
        self.files: dict[tuple[str, str], Path] = {}  # (placeholder, digest) -> file
        self.ids: dict[tuple[str, str], str] = {}  # (placeholder, digest) -> its tree's ID
        self.errors = 0
        """Writes and removals that failed (the folder's own errors, not a peer's)."""
        self.refused: dict[tuple[str, str], str] = {}
        """Items BT.CPP could not load (a name it reserves, say), or whose tree ID another
        file of the folder holds, with the reason: logged once, never written while the agent
        knows them. The agent may still run them; the BT.CPP program does not get them."""
        self._numbers: dict[tuple[str, str], int] = {}  # reserved, also for a failed write
        self._stale: set[Path] = set()  # files of this export no item owns any more
        self._next = 1
        stable = {f"{ident}.xml" for ident in self.tree_ids.values()}
        for path in sorted(self.folder.iterdir()):
            match = _FILE.fullmatch(path.name)
            if match is not None:
                self._adopt((match["slot"], match["digest"]), path)
                self._numbers.setdefault((match["slot"], match["digest"]), int(match["number"]))
                self._next = max(self._next, int(match["number"]) + 1)
            elif path.suffix == ".xml" and _GIVEN_ID.fullmatch(path.stem):
                key = _marked(path)
                if key is not None:
                    self._adopt(key, path)
            left = _TEMPORARY.fullmatch(path.name)
            if left is not None and (_FILE.fullmatch(left["name"]) or left["name"] in stable):
                for tmp in remove_stale_temporaries(self.folder / left["name"]):
                    log.info("removed %s (left by an interrupted write)", tmp.name)
        others = self._others()
        for ident in self.tree_ids.values():
            if ident in others:
                raise ValueError(
                    f"tree ID {ident!r} is already the tree of {others[ident]}; "
                    "Nav2 would load only one of the two files"
                )
            if self._foreign(self._stable(ident)):
                raise ValueError(
                    f"tree ID {ident!r}: its file {self._stable(ident)} is another file of "
                    "the folder, not one this export wrote"
                )
        self._known: frozenset[tuple[str, str]] | None = None

    def _adopt(self, key: tuple[str, str], path: Path) -> None:
        """A previous run's file of the item ``key``; a second file of one item (a run killed
        between writing its new file and removing its old one) is removed at the first sync."""
        if key in self.files:
            self._stale.add(path)
            return
        self.files[key] = path
        self.ids[key] = _main_id(path) or ""  # unreadable: written again if still known

    def _stable(self, ident: str) -> Path:
        """The file of the item whose tree ID was given (section 12.2): the same path for
        every item learned under that ID."""
        return self.folder / f"{ident}.xml"

    def _foreign(self, path: Path) -> bool:
        """Whether ``path`` is a file this export did not write (one it must never replace)."""
        return path.exists() and path not in self._mine()

    def _mine(self) -> set[Path]:
        return set(self.files.values()) | self._stale

    def _current(self, key: tuple[str, str], ident: str, given: bool) -> bool:
        """Whether the item's file holds its tree under ``ident`` at the path it belongs at."""
        path = self.files.get(key)
        if path is None or self.ids.get(key) != ident:
            return False
        return path == self._stable(ident) if given else _FILE.fullmatch(path.name) is not None

    def _others(self) -> dict[str, Path]:
        """The tree IDs of the folder's other ``.xml`` files (not this export's), each as Nav2
        reads it; a file that does not read holds none, as for Nav2."""
        mine = self._mine()
        held: dict[str, Path] = {}
        for path in sorted(self.folder.glob("*.xml")):
            if path in mine or not path.is_file():
                continue
            try:
                ids, _ = document_tree_ids(path.read_bytes())
            except (OSError, StringBTError):
                continue
            for ident in ids:
                held.setdefault(ident, path)
        return held

    def sync(self, knowledge: Iterable[Knowledge]) -> None:
        """Write the learned items (``source`` set) that have no file yet (or whose file holds
        another tree ID, or lies at another path: ``tree_ids`` changed since), in the order
        given, then remove the files of items no longer there. An item under a given ID
        replaces the file of the item it follows in place (section 12.2). Cheap when nothing
        changed."""
        learned = [item for item in knowledge if item.source is not None]
        known = frozenset((item.segment, item_digest(item.key, item.subtree)) for item in learned)
        if known == self._known:
            return
        self.refused = {key: why for key, why in self.refused.items() if key in known}
        for key in [key for key in self._numbers if key not in known]:
            del self._numbers[key]  # a failed write of an item forgotten since
        others: dict[str, Path] | None = None  # read once per sync that writes
        wanted: dict[tuple[str, str], tuple[str, bool]] = {}  # each item's tree ID, given?
        for item in learned:
            key = (item.segment, item_digest(item.key, item.subtree))
            given = item.key in self.tree_ids
            ident = tree_id(item, self.tree_ids)
            wanted[key] = (ident, given)
            if self._current(key, ident, given) or key in self.refused:
                continue
            if others is None:
                others = self._others()
            stable = self._stable(ident) if given else None
            # Another file holding the ID: an item of the same sequence in another placeholder,
            # or a forgotten item's file at another path (removed below, then this is written).
            held = [
                k
                for k in self.files
                if k != key and self.ids.get(k) == ident and (k in known or self.files[k] != stable)
            ]
            if held:
                continue
            try:
                if not NAME_RE.fullmatch(item.segment):
                    raise ValueError(f"placeholder {item.segment!r} is not a stringBT name")
                if ident in others:
                    raise ValueError(f"its tree ID {ident!r} is the tree of {others[ident]}")
                if stable is not None and self._foreign(stable):
                    raise ValueError(f"its file {stable} is another file of the folder")
                if any(btcpp_name(leaf.name) == ident for leaf in _leaves(item)):
                    raise ValueError(f"its tree ID {ident!r} names one of its own nodes")
                document = to_xml(item.item(), tree_id=ident)
            except (StringBTError, ValueError) as err:
                why = f"{err.code.value} {err.message}" if isinstance(err, StringBTError) else err
                self.refused[key] = str(why)
                log.warning("not exported to BT.CPP: %s: %s", item.key, self.refused[key])
                continue
            if stable is not None:
                path = stable
                head, _, rest = document.partition("\n")
                document = f"{head}\n{_MARK.format(slot=key[0], digest=key[1])}\n{rest}"
            else:
                if key not in self._numbers:
                    self._numbers[key] = self._next
                    self._next += 1
                path = self.folder / f"{self._numbers[key]:06d}-{key[0]}-{key[1]}.xml"
            try:
                write_atomic(path, document)
            except OSError as exc:
                self._failed(f"cannot write {path}: {exc}")
                continue
            previous = self.files.get(key)
            self.files[key], self.ids[key] = path, ident
            self._stale.discard(path)
            for replaced in [k for k, at in self.files.items() if k != key and at == path]:
                del self.files[replaced]  # the forgotten item this one replaced in place
                self.ids.pop(replaced, None)
            if previous is not None and previous != path:
                self._stale.add(previous)  # the item's file under its former ID or name
            log.info("wrote %s (tree %s)", path.name, ident)
        changed = False
        for key in [key for key in self.files if key not in known]:
            try:
                self.files[key].unlink(missing_ok=True)
            except OSError as exc:
                self._failed(f"cannot remove {self.files[key]}: {exc}")
                continue
            log.info("removed %s (forgotten)", self.files.pop(key).name)
            self.ids.pop(key, None)
            changed = True
        for path in sorted(self._stale):
            try:
                path.unlink(missing_ok=True)
            except OSError as exc:
                self._failed(f"cannot remove {path}: {exc}")
                continue
            log.info("removed %s (its item's file is another now)", path.name)
            self._stale.discard(path)
            changed = True
        if changed:
            try:
                fsync_folder(self.folder)
            except OSError as exc:
                self._failed(f"cannot flush {self.folder}: {exc}")
        current = {
            key for key, (ident, given) in wanted.items() if self._current(key, ident, given)
        }
        done = set(self.files) <= known and known <= current | self.refused.keys()
        if done and not self._stale:
            self._known = known

    def _failed(self, message: str) -> None:
        self.errors += 1
        log.warning("export of learned knowledge: %s", message)


def _usable(folder: Path) -> None:
    """Make ``folder`` if it is missing, and write a temporary file into it (a ``.tmp``, which
    Nav2 does not read) so that a folder the export could never write into fails at once."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".ktbt-", suffix=".tmp"):
            pass
    except OSError as exc:
        raise OSError(exc.errno, f"{folder}: {exc.strerror or exc}") from None


def _marked(path: Path) -> tuple[str, str] | None:
    """The item (placeholder, digest) whose ``<ID>.xml`` the export wrote at ``path``, read
    from the comment on its second line; None for any other file."""
    try:
        head = read_at_most(path, 512).decode("utf-8", "replace")
    except OSError:
        return None
    match = _MARKED.match(head)
    return (match["slot"], match["digest"]) if match is not None else None


def _main_id(path: Path) -> str | None:
    """The tree a file of this export runs (its ``main_tree_to_execute``), or None."""
    try:
        return document_tree_ids(path.read_bytes())[1]
    except (OSError, StringBTError):
        return None


def _leaves(item: Knowledge) -> list[Condition | Action]:
    return [node for node, _ in walk(item.item()) if isinstance(node, Condition | Action)]
