-- ktbt lsp for stringBT files (*.sbt) in Neovim 0.7 or later, without any plugin:
-- put this file in ~/.config/nvim/plugin/ (or source it from init.lua). The `ktbt` command
-- must be on PATH (the .venv/bin of a clone, or wherever `pip install 'ktbt[lsp]'` put it).
vim.filetype.add({ extension = { sbt = "stringbt" } })
-- Neovim 0.7 detects filetypes with filetype.vim, which calls *.sbt Scala's "sbt": say it first.
vim.api.nvim_create_autocmd({ "BufNewFile", "BufRead" }, {
  pattern = "*.sbt",
  callback = function(args) vim.bo[args.buf].filetype = "stringbt" end,
})

local client_id = nil

local function start(args)
  local config = {
    name = "ktbt",
    cmd = { "ktbt", "lsp" },
    root_dir = vim.fn.fnamemodify(vim.api.nvim_buf_get_name(args.buf), ":p:h"),
  }
  if vim.lsp.start then -- Neovim 0.8 and later
    vim.lsp.start(config, { bufnr = args.buf })
    return
  end
  if client_id == nil or vim.lsp.get_client_by_id(client_id) == nil then
    client_id = vim.lsp.start_client(config)
  end
  vim.lsp.buf_attach_client(args.buf, client_id)
end

vim.api.nvim_create_autocmd("FileType", { pattern = "stringbt", callback = start })

-- Format the buffer to the canonical form with :KtbtFormat (or bind it to a key).
vim.api.nvim_create_user_command("KtbtFormat", function()
  if vim.lsp.buf.format then
    vim.lsp.buf.format({ name = "ktbt", timeout_ms = 5000 })
  else
    vim.lsp.buf.formatting_sync(nil, 5000)
  end
end, {})
