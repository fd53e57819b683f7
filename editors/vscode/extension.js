// The stringBT extension: the grammar and language configuration are declared in package.json;
// this starts `ktbt lsp` (docs/howto/editors.md) for every stringBT document.
"use strict";
const vscode = require("vscode");
const { LanguageClient, TransportKind } = require("vscode-languageclient/node");

let client;

function activate(context) {
  const settings = vscode.workspace.getConfiguration("ktbt");
  const server = {
    command: settings.get("command", "ktbt"),
    args: ["lsp", ...settings.get("arguments", [])],
    transport: TransportKind.stdio,
  };
  client = new LanguageClient(
    "ktbt",
    "ktbt lsp",
    { run: server, debug: server },
    {
      documentSelector: [
        { scheme: "file", language: "stringbt" },
        { scheme: "untitled", language: "stringbt" },
      ],
    },
  );
  context.subscriptions.push(client);
  return client.start();
}

function deactivate() {
  return client ? client.stop() : undefined;
}

module.exports = { activate, deactivate };
