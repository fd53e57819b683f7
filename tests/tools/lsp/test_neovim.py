"""Neovim, Debian's package, as a real editor of stringBT: headless, configured with exactly the
file docs/howto/editors.md shows (``editors/nvim/ktbt.lua``), it opens a file with a mistake in
a project whose ktbt.toml names the door robot's vocabulary, receives the diagnostic, completes
an action's name, follows an edit (incremental sync) to the next diagnostic, and formats the
file to the canonical form. A Lua script drives it and writes what it saw to a file the test
reads; every wait in it is ``vim.wait`` on a condition, bounded.

Without ``nvim`` on the PATH the test says it skipped (``apt-get install neovim``)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ktbt_proto.formatter import format_tree
from ktbt_proto.syntax import parse
from tests.door_robot import VOCABULARY

ROOT = Path(__file__).resolve().parents[3]
CONFIG = ROOT / "editors" / "nvim" / "ktbt.lua"
NVIM = shutil.which("nvim")

pytestmark = [
    pytest.mark.network,
    pytest.mark.skipif(NVIM is None, reason="no nvim on PATH (apt-get install neovim)"),
]

MISTAKE = "<sq>\n<c>(DoorClosed)   <a>(Fly)\n<a>(\n"
"""An unknown action, then a leaf still being typed (the input ends inside it)."""
TYPED = "<a>(Push)<e>"
"""What the script types over the last line: the file then parses, with one problem left (and
the re-run trap's warning: the root is now a flat knowledge item with two actions)."""

DRIVER = r"""
local out = {}
local function say(line) table.insert(out, line) end
local function code(d)
  return d.code or (d.user_data and d.user_data.lsp and d.user_data.lsp.code) or "?"
end
local function codes()
  local found = {}
  for _, d in ipairs(vim.diagnostic.get(0)) do table.insert(found, code(d)) end
  table.sort(found)
  return table.concat(found, ",")
end
local function show(d)
  say(string.format("diagnostic %d:%d-%d:%d %s %d %s", d.lnum, d.col, d.end_lnum, d.end_col,
    code(d), d.severity, d.message))
end
local ok, err = pcall(function()
  if not vim.wait(30000, function() return #vim.diagnostic.get(0) > 0 end, 20) then
    error("no diagnostics came")
  end
  for _, d in ipairs(vim.diagnostic.get(0)) do show(d) end
  local params = {
    textDocument = { uri = vim.uri_from_bufnr(0) },
    position = { line = 2, character = 4 },
  }
  local answers = vim.lsp.buf_request_sync(0, "textDocument/completion", params, 10000) or {}
  for _, answer in pairs(answers) do
    local items = answer.result and (answer.result.items or answer.result) or {}
    for _, item in ipairs(items) do say("completion " .. item.label) end
  end
  vim.api.nvim_buf_set_lines(0, 2, 3, false, { vim.env.KTBT_TYPED })
  if not vim.wait(30000, function() return codes() == "SBT306,SBT502" end, 20) then
    error("the edit was not checked: " .. codes())
  end
  for _, d in ipairs(vim.diagnostic.get(0)) do show(d) end
  vim.cmd("KtbtFormat")
  for _, line in ipairs(vim.api.nvim_buf_get_lines(0, 0, -1, false)) do
    say("formatted " .. line)
  end
end)
if not ok then say("error " .. tostring(err)) end
vim.fn.writefile(out, vim.env.KTBT_NVIM_OUT)
vim.cmd("qa!")
"""


def _gone(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return True
    return False


def test_neovim_shows_the_diagnostic_completes_follows_an_edit_and_formats(
    tmp_path: Path,
) -> None:
    (tmp_path / "door.toml").write_text(VOCABULARY, encoding="utf-8")
    (tmp_path / "ktbt.toml").write_text('vocabulary = "door.toml"\n', encoding="utf-8")
    (tmp_path / "door.sbt").write_text(MISTAKE, encoding="utf-8")
    driver = tmp_path / "driver.lua"
    driver.write_text(DRIVER, encoding="utf-8")
    out = tmp_path / "seen.txt"
    env = {
        **os.environ,
        "PATH": str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""),
        "KTBT_NVIM_OUT": str(out),
        "KTBT_TYPED": TYPED,
        "XDG_STATE_HOME": str(tmp_path / "state"),  # nvim's LSP log, not the user's
        "XDG_CACHE_HOME": str(tmp_path / "cache"),
    }
    assert NVIM is not None
    command = [NVIM, "--headless", "--clean", "-u", str(CONFIG), "-c", f"luafile {driver}"]
    editor = subprocess.Popen(
        [*command, "door.sbt"],
        cwd=tmp_path,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        _, stderr = editor.communicate(timeout=90)
        # The editor closed its server on the way out: nothing of the session is left.
        deadline = time.monotonic() + 15
        while not _gone(editor.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _gone(editor.pid), "ktbt lsp outlived the editor"
    finally:
        if not _gone(editor.pid):
            os.killpg(editor.pid, signal.SIGKILL)
        editor.wait()
    seen = out.read_text(encoding="utf-8").splitlines()
    assert not [line for line in seen if line.startswith("error")], (seen, stderr)
    assert seen[0] == "diagnostic 3:0-3:0 SBT104 1 input ends inside <a> at 3:1; expected a name"
    assert [line for line in seen if line.startswith("completion")] == [
        "completion GraspHandle",
        "completion Push",
        "completion TurnHandle",
    ]
    assert "diagnostic 1:22-1:25 SBT306 1 unknown action 'Fly'" in seen
    assert [line for line in seen if " SBT502 2 " in line] == [
        "diagnostic 1:18-1:26 SBT502 2 <a>(Fly) runs again on every tick while <a>(Push) is "
        "RUNNING: if it must run once, put the actions in one <msq>...<e> (the memory form)"
    ]
    fixed = MISTAKE.replace("<a>(\n", TYPED + "\n")
    formatted = [line.removeprefix("formatted ") for line in seen if line.startswith("formatted")]
    assert formatted == format_tree(parse(fixed)).splitlines()
