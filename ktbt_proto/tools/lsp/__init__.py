"""``ktbt lsp``: a language server for stringBT files (``.sbt``), over stdio, in the ``lsp`` extra.

An editor gets what the command line already knows, as you type: every ``SBT`` problem with
its range (spec/stringbt.md section 9; warnings as warnings, section 4.1), the canonical pretty
form (section 7), completion and hover from the robot's vocabulary (section 5.1), an outline,
folding, go to definition, certain fixes and semantic highlighting that follows the grammar
(section 2). The modules below the server (:mod:`.document`, :mod:`.outline`,
:mod:`.vocabulary`, :mod:`.diagnostics`, :mod:`.formatting`, :mod:`.assist`,
:mod:`.navigation`) are plain functions of a document's text; :mod:`.server` wires them to
pygls, and :mod:`.command` adds ``ktbt lsp`` through the ``ktbt.commands`` entry point, so
``ktbt`` works without the extra.
"""
