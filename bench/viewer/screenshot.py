"""``python -m bench.viewer.screenshot URL OUT.png``: a picture of a served viewer page, from headless Chromium.

Chromium is driven over its DevTools protocol (a websocket; the ``websockets`` package comes with viser): open
the page, wait in real time for the client to connect and draw (a headless virtual-time budget stalls the
page's own websocket), then capture the window. Rendering is software WebGL (SwiftShader): no GPU needed.
"""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from bench.errors import ArgumentParser, BenchError, ConfigError, failed

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "chrome")
DISMISS = "document.querySelectorAll('.mantine-Notification-closeButton, [class*=CloseButton]').forEach(b => b.click())"


def find_browser() -> str | None:
    return next((path for name in BROWSERS if (path := shutil.which(name))), None)


def screenshot(url: str, out: Path, wait_s: float = 20.0, size: tuple[int, int] = (1200, 800)) -> Path:
    """Open ``url`` in headless Chromium, wait ``wait_s`` seconds, write the window as PNG to ``out``."""
    from websockets.sync.client import connect

    browser = find_browser()
    if browser is None:
        raise ConfigError(f"expected a Chromium browser on PATH ({', '.join(BROWSERS)}), found none")
    with tempfile.TemporaryDirectory() as profile:
        proc = subprocess.Popen(
            [
                browser,
                "--headless=new",
                "--no-sandbox",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--hide-scrollbars",
                "--remote-debugging-port=0",
                f"--user-data-dir={profile}",
                f"--window-size={size[0]},{size[1]}",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            port_file = Path(profile) / "DevToolsActivePort"
            deadline = time.monotonic() + 60
            while not port_file.is_file() or not port_file.read_text().strip():
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise ConfigError(f"expected {browser} to start with a DevTools port, found none within 60 s")
                time.sleep(0.2)
            port = int(port_file.read_text().split()[0])
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=30) as r:
                page = next(t for t in json.load(r) if t.get("type") == "page")
            with connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=30) as ws:
                ids = iter(range(1, 1_000_000))

                def call(method: str, **params) -> dict:
                    n = next(ids)
                    ws.send(json.dumps({"id": n, "method": method, "params": params}))
                    while True:
                        reply = json.loads(ws.recv(timeout=120))
                        if reply.get("id") == n:
                            if "error" in reply:
                                raise ConfigError(f"expected Chromium to do {method}, found: {reply['error']}")
                            return reply.get("result", {})

                call("Page.navigate", url=url)
                time.sleep(wait_s)
                call("Runtime.evaluate", expression=DISMISS)  # the toast saying WebGL runs in software
                time.sleep(1.0)
                data = call("Page.captureScreenshot", format="png")["data"]
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(base64.b64decode(data))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m bench.viewer.screenshot", description=__doc__.splitlines()[0])
    parser.add_argument("url", help="the page, e.g. http://127.0.0.1:8080 (pocketbench view serving)")
    parser.add_argument("out", type=Path, help="PNG path")
    parser.add_argument("--wait", type=float, default=20.0, help="seconds to let the page draw (default 20)")
    parser.add_argument("--size", default="1200x800", help="window WIDTHxHEIGHT px (default 1200x800)")
    args = parser.parse_args(argv)
    try:
        w, _, h = args.size.partition("x")
        if not (w.isdigit() and h.isdigit()):
            raise ConfigError(f"--size: expected WIDTHxHEIGHT, found {args.size}")
        path = screenshot(args.url, args.out, args.wait, (int(w), int(h)))
    except BenchError as exc:
        return failed(exc)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
