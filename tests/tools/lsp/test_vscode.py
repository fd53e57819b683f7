"""The VS Code extension in ``editors/vscode``: its TextMate grammar passes its annotated samples
(``test/*.sbt``, vscode-tmgrammar-test from the npm registry), it packages to a ``.vsix`` with
@vscode/vsce, and the documentation's own stringBT highlighter (``docs/_ext/ktbt_pages.py``)
agrees with the grammar on the same samples, so that the two never disagree on what a token is.

VS Code itself cannot be run here; its LSP client is the vscode-languageclient the ``.vsix``
carries, and ``ktbt lsp`` is tested over a real client in test_server.py. Without ``npm`` on the
PATH the packaging test says it skipped."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
EXTENSION = ROOT / "editors" / "vscode"
SAMPLES = sorted((EXTENSION / "test").glob("*.sbt"))
NPM = shutil.which("npm")
MARKS = re.compile(r"^#(\s*)(\^+|<-+)\s+(\S+)")


def assertions(sample: Path) -> tuple[list[str], list[tuple[int, int, int, str]]]:
    """A vscode-tmgrammar-test sample: its source lines, and each assertion as (line, first
    column, last column + 1, scope)."""
    source: list[str] = []
    marks: list[tuple[int, int, int, str]] = []
    for line in sample.read_text(encoding="utf-8").splitlines():
        if line.startswith("# SYNTAX TEST"):
            continue
        match = MARKS.match(line)
        if match is None:
            source.append(line)
            continue
        if match[2].startswith("<"):
            start, end = 0, len(match[2]) - 1
        else:
            start = line.index("^")
            end = start + len(match[2])
        marks.append((len(source) - 1, start, end, match[3]))
    return source, marks


def _lexer() -> object:
    sys.path.insert(0, str(ROOT / "docs" / "_ext"))
    try:
        from ktbt_pages import StringBTLexer  # type: ignore[import-not-found]
    finally:
        sys.path.remove(str(ROOT / "docs" / "_ext"))
    return StringBTLexer()


def test_the_docs_highlighter_agrees_with_the_grammar_on_its_samples() -> None:
    from pygments.token import (  # type: ignore[import-untyped]
        Comment,
        Keyword,
        Name,
        Number,
        Operator,
        String,
    )

    allowed = {
        "keyword.control.tag.stringbt": {Keyword},
        "invalid.illegal.tag.stringbt": {Keyword},  # the pages do not single out unknown tags
        "comment.line.number-sign.stringbt": {Comment.Single},
        "string.quoted.double.stringbt": {String},
        "constant.character.escape.stringbt": {String},
        "constant.numeric.stringbt": {Number},
        "constant.language.boolean.stringbt": {Keyword.Constant},
        "entity.name.function.stringbt": {Name},
        "entity.name.namespace.stringbt": {Name},
        "variable.parameter.stringbt": {Name},
        "keyword.operator.logical.stringbt": {Operator, Name},  # the pages read "!X" as a name
    }
    lexer = _lexer()
    assert SAMPLES
    for sample in SAMPLES:
        source, marks = assertions(sample)
        assert marks, sample
        kinds: list[list[object]] = []
        for written in source:
            row: list[object] = []
            for token, text in lexer.get_tokens(written + "\n"):  # type: ignore[attr-defined]
                row += [token] * len(text)
            kinds.append(row)
        for number, start, end, scope in marks:
            for column in range(start, end):
                token = kinds[number][column]
                assert token in allowed[scope], (sample.name, number, column, scope, token)


@pytest.mark.network
@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.skipif(NPM is None, reason="no npm on PATH (apt-get install npm)")
def test_the_extension_passes_its_grammar_tests_and_packages_to_a_vsix(tmp_path: Path) -> None:
    assert NPM is not None
    folder = tmp_path / "vscode"
    shutil.copytree(EXTENSION, folder, ignore=shutil.ignore_patterns("node_modules", "*.vsix"))

    def npm(*args: str) -> str:
        done = subprocess.run(
            [NPM, *args], cwd=folder, capture_output=True, text=True, timeout=500, check=False
        )
        assert done.returncode == 0, f"npm {' '.join(args)}\n{done.stdout}\n{done.stderr}"
        return done.stdout

    npm("ci", "--no-audit", "--no-fund")
    tested = npm("test")
    for sample in SAMPLES:
        assert f"{sample.relative_to(EXTENSION)} run successfuly" in tested
    node = shutil.which("node")
    assert node is not None
    subprocess.run([node, "--check", "extension.js"], cwd=folder, check=True)
    npm("run", "package")
    with zipfile.ZipFile(folder / "ktbt-stringbt.vsix") as vsix:
        names = set(vsix.namelist())
    assert {
        "extension/package.json",
        "extension/extension.js",
        "extension/language-configuration.json",
        "extension/syntaxes/stringbt.tmLanguage.json",
        "extension/node_modules/vscode-languageclient/package.json",
    } <= names
    assert not [n for n in names if n.startswith("extension/test/")]
    assert not [n for n in names if "/node_modules/@vscode/vsce/" in n]  # tools stay out
