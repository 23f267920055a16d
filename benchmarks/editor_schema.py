"""What an editor shows for a config: yaml-language-server (the YAML language server VS Code, Neovim and others run)
opened on a YAML file whose first line names a schema (``# yaml-language-server: $schema=robot.schema.json``), and
its diagnostics and completions printed.  docs/config.md shows a run.

    npm install yaml-language-server@1          # somewhere; pass its node_modules/.bin/yaml-language-server
    PYTHONPATH=. python benchmarks/editor_schema.py SERVER FILE.yaml [LINE:COLUMN]

LINE:COLUMN (0-based, as LSP counts) asks for completions there too.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path


class Lsp:
    """A minimal LSP client over the server's stdin and stdout."""

    def __init__(self, server: str):
        self.proc = subprocess.Popen([server, "--stdio"], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.next_id = 0

    def send(self, method: str, params: dict, request: bool = True) -> int | None:
        msg = {"jsonrpc": "2.0", "method": method, "params": params}
        if request:
            self.next_id += 1
            msg["id"] = self.next_id
        body = json.dumps(msg).encode()
        self.proc.stdin.write(b"Content-Length: %d\r\n\r\n" % len(body) + body)
        self.proc.stdin.flush()
        return msg.get("id")

    def read(self) -> dict:
        length = 0
        while (line := self.proc.stdout.readline().strip()):
            if line.lower().startswith(b"content-length:"):
                length = int(line.split(b":")[1])
        return json.loads(self.proc.stdout.read(length))

    def wait(self, pred, timeout: float = 30.0) -> dict:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.read()
            if msg.get("method") == "workspace/configuration":        # the server asks for its settings
                self.reply(msg["id"], [{"validate": True, "completion": True, "hover": True}] *
                           len(msg["params"]["items"]))
            elif "id" in msg and "method" in msg:                       # any other request: an empty answer
                self.reply(msg["id"], None)
            if pred(msg):
                return msg
        raise TimeoutError("no answer from the language server")

    def reply(self, mid, result) -> None:
        body = json.dumps({"jsonrpc": "2.0", "id": mid, "result": result}).encode()
        self.proc.stdin.write(b"Content-Length: %d\r\n\r\n" % len(body) + body)
        self.proc.stdin.flush()


def main(argv: list[str]) -> int:
    server, path = argv[0], Path(argv[1]).resolve()
    lsp = Lsp(server)
    uri = path.as_uri()
    rid = lsp.send("initialize", {"processId": None, "rootUri": path.parent.as_uri(), "capabilities": {
        "workspace": {"configuration": True},
        "textDocument": {"completion": {"completionItem": {"snippetSupport": False}}}}})
    lsp.wait(lambda m: m.get("id") == rid)
    lsp.send("initialized", {}, request=False)
    lsp.send("workspace/didChangeConfiguration", {"settings": {"yaml": {"validate": True, "completion": True}}},
             request=False)
    lsp.send("textDocument/didOpen", {"textDocument": {"uri": uri, "languageId": "yaml", "version": 1,
                                                       "text": path.read_text()}}, request=False)
    diag = lsp.wait(lambda m: m.get("method") == "textDocument/publishDiagnostics" and m["params"]["uri"] == uri)
    lines = path.read_text().splitlines()
    for d in diag["params"]["diagnostics"]:
        line = d["range"]["start"]["line"]
        print(f"{path.name}:{line + 1}: {d['message']}    | {lines[line].strip()}")
    print(f"{len(diag['params']['diagnostics'])} diagnostic(s)")
    if len(argv) > 2:
        line, col = map(int, argv[2].split(":"))
        rid = lsp.send("textDocument/completion", {"textDocument": {"uri": uri},
                                                   "position": {"line": line, "character": col}})
        items = lsp.wait(lambda m: m.get("id") == rid)["result"]
        items = items.get("items", []) if isinstance(items, dict) else items or []
        print(f"completions at {line + 1}:{col + 1}: " + ", ".join(sorted(i["label"] for i in items)))
    lsp.proc.kill()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
