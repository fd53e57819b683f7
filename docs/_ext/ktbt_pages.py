"""What the pages need beyond MyST: a highlighter for stringBT (and plain text for the grammar's
lark blocks), and the spec's links to its own files, which the spec pages include unchanged,
made into download links from the page that includes them (``include-read``).

The spec's files stay byte-identical in ``spec/``: only what the build reads of them here is
rewritten, link targets alone.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path
from typing import Any, ClassVar

from pygments.lexer import RegexLexer
from pygments.lexers.special import TextLexer
from pygments.token import Comment, Keyword, Name, Number, Operator, Punctuation, String, Text
from sphinx.application import Sphinx

ROOT = Path(__file__).resolve().parents[2]
LINK = re.compile(r"\]\(([^)\s#]+)(#[^)\s]*)?\)")


class StringBTLexer(RegexLexer):
    """stringBT: tags, names, arguments and comments (spec/stringbt.md section 2)."""

    name = "stringBT"
    aliases: ClassVar[list[str]] = ["stringbt"]
    tokens: ClassVar[dict[str, Any]] = {
        "root": [
            (r"#[^\n]*", Comment.Single),
            (r"<(?:Root|[a-z][a-z0-9]*)>", Keyword),
            (r'"(?:[^"\\]|\\.)*"', String),
            (r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", Number),
            (r"(?:true|false)\b", Keyword.Constant),
            (r"!?[A-Za-z_][A-Za-z0-9_.]*", Name),
            (r"[(),=]", Punctuation),
            (r"!", Operator),
            (r"\s+", Text),
        ]
    }


def relink(app: Sphinx, relative_path: Path, parent_docname: str, content: list[str]) -> None:
    """In an included file from ``spec/``, a link to a file beside it (not a page) becomes a
    download link to that file."""
    source = (Path(app.srcdir) / relative_path).resolve()
    if source.parent != ROOT / "spec":
        return
    page_dir = (Path(app.srcdir) / app.env.docname).parent

    def target(match: re.Match[str]) -> str:
        link, anchor = match[1], match[2] or ""
        if re.match(r"[a-z]+:", link) or link.endswith(".md"):
            return match[0]
        path = (source.parent / link).resolve()
        relative = posixpath.relpath(path.as_posix(), page_dir.as_posix())
        return f"](path:{relative}{anchor})"

    content[0] = LINK.sub(target, content[0])


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_lexer("stringbt", StringBTLexer)
    app.add_lexer("lark", TextLexer)
    app.connect("include-read", relink)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
