"""Hypothesis strategies for stringBT trees and for arbitrary token soup."""

from __future__ import annotations

from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.tree import (
    Comments,
    Inverter,
    Node,
    Parallel,
    Placeholder,
    RunTimer,
    Selector,
    Wait,
    WaitTimer,
)

RESERVED = {"true", "false"}

names = st.from_regex(
    r"[A-Za-z_][A-Za-z0-9_]{0,8}(\.[A-Za-z_][A-Za-z0-9_]{0,4})?", fullmatch=True
).filter(lambda s: s not in RESERVED)

values = st.one_of(
    st.booleans(),
    st.integers(-(10**12), 10**12),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(st.characters(codec="utf-8"), max_size=12),
)
args = st.lists(st.tuples(names, values), max_size=3, unique_by=lambda kv: kv[0]).map(tuple)
comment_text = st.text(st.characters(codec="utf-8", exclude_characters="\r\n"), max_size=20).map(
    str.rstrip
)
comment_lists = st.lists(comment_text, max_size=2).map(tuple)


@st.composite
def comments(draw: st.DrawFn, container: bool) -> Comments | None:
    if not draw(st.booleans()):
        return None
    trailing = draw(st.none() | comment_text)
    if not container:
        return Comments(draw(comment_lists), trailing)
    return Comments(
        draw(comment_lists), trailing, draw(comment_lists), draw(st.none() | comment_text)
    )


def leaves(with_comments: bool) -> st.SearchStrategy[Node]:
    notes = comments(False) if with_comments else st.none()
    return st.one_of(
        st.builds(kp.Condition, names, st.booleans(), args, comments=notes),
        st.builds(kp.Action, names, args, comments=notes),
        st.builds(Wait, st.integers(0, 10**6), st.just("ticks"), comments=notes),
        st.builds(
            Wait,
            st.floats(0, 1e6, allow_nan=False) | st.integers(0, 1000),
            st.just("seconds"),
            comments=notes,
        ),
    )


def trees(with_comments: bool = False, valid: bool = False) -> st.SearchStrategy[Node]:
    """Random trees. ``valid``: arities and thresholds follow the validation rules (placeholder
    names may still repeat; tests that validate rename them)."""
    notes = comments(True) if with_comments else st.none()

    def extend(children: st.SearchStrategy[Node]) -> st.SearchStrategy[Node]:
        many = st.lists(children, min_size=1 if valid else 0, max_size=4).map(tuple)
        one = children.map(lambda c: (c,)) if valid else many
        return st.one_of(
            st.builds(kp.SequenceNode, many, st.booleans(), comments=notes),
            st.builds(Selector, many, st.booleans(), comments=notes),
            many.flatmap(
                lambda ch: st.builds(
                    Parallel,
                    st.just(ch),
                    st.none() | st.integers(1, max(len(ch), 1)),
                    comments=notes,
                )
            ),
            st.builds(Inverter, one, comments=notes),
            st.builds(WaitTimer, one, st.integers(0, 10**6), comments=notes),
            st.builds(RunTimer, one, st.integers(0, 10**6), comments=notes),
            st.builds(
                Placeholder,
                st.lists(children, max_size=3).map(tuple),
                names,
                comments=notes,
            ),
        )

    return st.recursive(leaves(with_comments), extend, max_leaves=25)


SOUP_TOKENS = [
    "<Root>",
    "<sq>",
    "<msq>",
    "<sl>",
    "<msl>",
    "<pl>",
    "<neg>",
    "<tt1>",
    "<tt2>",
    "<k>",
    "<c>",
    "<a>",
    "<w>",
    "<wt>",
    "<e>",
    "<foo>",
    "<>",
    "(",
    ")",
    ",",
    "=",
    "!",
    "x",
    "Go",
    "a.b",
    "true",
    "false",
    "0",
    "-3",
    "2.5",
    "1e3",
    '"s"',
    '"a#b"',
    "# note\n",
    "#\n",
    "$",
    ".",
    "-",
    "<",
    ">",
    "\n",
    " ",
]


@st.composite
def soup(draw: st.DrawFn) -> str:
    """Text built from stringBT's own tokens in random order: mostly invalid, sometimes valid."""
    parts = draw(st.lists(st.sampled_from(SOUP_TOKENS), max_size=30))
    seps = draw(
        st.lists(st.sampled_from(["", "", " ", "\n"]), min_size=len(parts), max_size=len(parts))
    )
    return "".join(p + s for p, s in zip(parts, seps, strict=True))
