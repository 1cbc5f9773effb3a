"""Loading QA pages in headless Chromium: console errors, horizontal overflow, screenshots.

Chromium is driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``:
JSON messages separated by NUL bytes on file descriptors 3 and 4), so nothing but the
standard library and the ``chromium`` binary is needed, and no network port is opened.
Debian: ``apt-get install chromium`` (``scripts/install_chromium.sh``).

Command line (the screenshots of ``docs/img`` are taken with it)::

    python -m towerpipe.products.qa.browser results/demo/qa/index.html --screenshot docs/img/qa_index.png
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Where Chromium is looked for (``TOWERPIPE_CHROMIUM`` overrides).
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "chrome")

#: Flags for a quiet, offline, throw-away browser.
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--remote-debugging-pipe",
)

#: The width the pages must fit without horizontal scrolling (px).
PAGE_WIDTH = 1280

#: DevTools protocol field that routes a command to an attached page target.
_ROUTE = "sessionId"

#: Run in the page after it loaded: the document's overflow and the elements sticking out.
_OVERFLOW_JS = """(() => {
  const root = document.documentElement, limit = root.clientWidth;
  const out = [];
  for (const el of document.body.querySelectorAll('*')) {
    const r = el.getBoundingClientRect();
    const scrolls = el.scrollWidth > el.clientWidth + 1 && getComputedStyle(el).overflowX !== 'visible';
    if (r.right > limit + 1 || scrolls) {
      out.push({tag: el.tagName.toLowerCase(), cls: el.className && String(el.className),
                right: Math.round(r.right), scroll: scrolls ? el.scrollWidth - el.clientWidth : 0});
    }
  }
  return JSON.stringify({scrollWidth: root.scrollWidth, clientWidth: limit, wide: out.slice(0, 20),
                         title: document.title});
})()"""


class BrowserError(RuntimeError):
    """Chromium could not be started or did not answer."""


def find_chromium() -> str | None:
    """Path of the Chromium binary, or None."""
    env = os.environ.get("TOWERPIPE_CHROMIUM")
    if env:
        return env if Path(env).exists() else None
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


@dataclass
class PageCheck:
    """What loading a page showed."""

    url: str
    title: str
    scroll_width: int
    client_width: int
    console_errors: list[str] = field(default_factory=list)
    overflowing: list[dict[str, Any]] = field(default_factory=list)

    @property
    def overflow_px(self) -> int:
        """How far the document scrolls horizontally (0: it fits)."""
        return max(0, self.scroll_width - self.client_width)

    @property
    def ok(self) -> bool:
        return not self.console_errors and not self.overflow_px and not self.overflowing

    def problems(self) -> list[str]:
        """One line per problem."""
        out = [f"console error: {e}" for e in self.console_errors]
        if self.overflow_px:
            out.append(f"the page scrolls sideways by {self.overflow_px} px at {self.client_width} px")
        out += [
            f"<{w['tag']} class={w['cls']!r}> sticks out (right edge {w['right']} px, scrolls {w['scroll']} px)"
            for w in self.overflowing
        ]
        return out


class Browser:
    """A headless Chromium driven over the DevTools pipe; use as a context manager.

    Parameters
    ----------
    binary
        The Chromium executable (default: :func:`find_chromium`).
    timeout
        Seconds to wait for any answer.
    """

    def __init__(self, binary: str | None = None, timeout: float = 60.0):
        self.binary = binary or find_chromium()
        if not self.binary:
            raise BrowserError("chromium not found; install it (scripts/install_chromium.sh) or set TOWERPIPE_CHROMIUM")
        self.timeout = timeout
        self._id = 0
        self._buf = b""
        self._events: list[dict[str, Any]] = []

    # ---- process and pipe
    def __enter__(self) -> Browser:
        self._profile = tempfile.mkdtemp(prefix="towerpipe-chromium-")
        to_chrome_r, self._to_chrome = os.pipe()
        self._from_chrome, from_chrome_w = os.pipe()

        def fds() -> None:  # in the child: the pipe ends on fds 3 (commands in) and 4 (answers out)
            os.dup2(to_chrome_r, 3)
            os.dup2(from_chrome_w, 4)

        self.proc = subprocess.Popen(
            [self.binary, *CHROMIUM_FLAGS, f"--user-data-dir={self._profile}", "about:blank"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            preexec_fn=fds,
            pass_fds=(3, 4),
        )
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        return self

    def __exit__(self, *exc: Any) -> None:
        try:
            if self.proc.poll() is None:
                self._write({"id": self._next_id(), "method": "Browser.close"})
                self.proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        finally:
            for fd in (self._to_chrome, self._from_chrome):
                try:
                    os.close(fd)
                except OSError:
                    pass
            if self.proc.stderr:
                self.proc.stderr.close()
            shutil.rmtree(self._profile, ignore_errors=True)

    def _next_id(self) -> int:
        self._id += 1
        return self._id

    def _write(self, msg: dict[str, Any]) -> None:
        os.write(self._to_chrome, json.dumps(msg).encode() + b"\0")

    def _read(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self._from_chrome], [], [], max(0.0, left))
            if not ready:
                raise BrowserError(f"chromium did not answer within {self.timeout:.0f} s")
            chunk = os.read(self._from_chrome, 1 << 20)
            if not chunk:
                err = self.proc.stderr.read().decode(errors="replace")[-2000:] if self.proc.stderr else ""
                raise BrowserError(f"chromium exited (status {self.proc.poll()}): {err.strip()}")
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return json.loads(raw)

    def send(self, method: str, params: dict[str, Any] | None = None, route: str | None = None) -> dict[str, Any]:
        """Send a protocol command (to the page ``route`` when given) and return its result."""
        msg: dict[str, Any] = {"id": self._next_id(), "method": method, "params": params or {}}
        if route:
            msg[_ROUTE] = route
        self._write(msg)
        deadline = time.monotonic() + self.timeout
        while True:
            answer = self._read(deadline)
            if answer.get("id") == msg["id"]:
                if "error" in answer:
                    raise BrowserError(f"{method}: {answer['error'].get('message')}")
                return answer.get("result", {})
            self._events.append(answer)

    def wait_for(self, method: str, route: str) -> dict[str, Any]:
        """Wait for a protocol event of the page ``route``."""
        deadline = time.monotonic() + self.timeout
        while True:
            for i, ev in enumerate(self._events):
                if ev.get("method") == method and ev.get(_ROUTE) == route:
                    return self._events.pop(i)
            self._events.append(self._read(deadline))

    # ---- pages
    def open(self, path: str | os.PathLike[str], width: int = PAGE_WIDTH, height: int = 900) -> str:
        """Load a local page in a new tab of ``width`` × ``height`` CSS px; returns the tab's route."""
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        route = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})[_ROUTE]
        for domain in ("Page", "Runtime", "Log"):
            self.send(f"{domain}.enable", route=route)
        self.send(
            "Emulation.setDeviceMetricsOverride",
            {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
            route=route,
        )
        self._events = [e for e in self._events if e.get(_ROUTE) != route]
        self.send("Page.navigate", {"url": Path(path).resolve().as_uri()}, route=route)
        self.wait_for("Page.loadEventFired", route)
        return route

    def check(self, path: str | os.PathLike[str], width: int = PAGE_WIDTH) -> PageCheck:
        """Load ``path`` at ``width`` px and report console errors and horizontal overflow."""
        route = self.open(path, width)
        res = self.send("Runtime.evaluate", {"expression": _OVERFLOW_JS, "returnByValue": True}, route=route)
        found = json.loads(res["result"]["value"])
        errors = []
        for ev in self._events:
            if ev.get(_ROUTE) != route:
                continue
            p = ev.get("params", {})
            if ev.get("method") == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                errors.append(" ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", [])))
            elif ev.get("method") == "Runtime.exceptionThrown":
                d = p.get("exceptionDetails", {})
                errors.append(d.get("exception", {}).get("description") or d.get("text", "exception"))
            elif ev.get("method") == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
                e = p["entry"]
                errors.append(f"{e.get('text', '')} {e.get('url', '')}".strip())
        return PageCheck(
            url=Path(path).resolve().as_uri(),
            title=found["title"],
            scroll_width=found["scrollWidth"],
            client_width=found["clientWidth"],
            console_errors=errors,
            overflowing=found["wide"],
        )

    def screenshot(
        self, path: str | os.PathLike[str], out_png: str | os.PathLike[str], width: int = PAGE_WIDTH, height: int = 1400
    ) -> Path:
        """A PNG of the top ``height`` px of the page at ``width`` px."""
        route = self.open(path, width, height)
        shot = self.send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": False}, route=route)
        out = Path(out_png)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(base64.b64decode(shot["data"]))
        return out


def main(argv: list[str] | None = None) -> int:
    """Check pages (exit status 1 on a problem) and optionally take a screenshot of each."""
    ap = argparse.ArgumentParser(prog="python -m towerpipe.products.qa.browser", description=main.__doc__)
    ap.add_argument("pages", nargs="+", help="HTML files")
    ap.add_argument("--width", type=int, default=PAGE_WIDTH)
    ap.add_argument(
        "--height",
        type=int,
        action="append",
        default=[],
        help="screenshot height (px) per page, in order (default 1400)",
    )
    ap.add_argument("--screenshot", action="append", default=[], help="PNG per page, in order")
    args = ap.parse_args(argv)
    heights = args.height or [1400]
    bad = 0
    with Browser() as b:
        for i, page in enumerate(args.pages):
            check = b.check(page, args.width)
            for line in check.problems():
                print(f"{page}: {line}")
            bad += not check.ok
            if i < len(args.screenshot):
                b.screenshot(page, args.screenshot[i], args.width, heights[min(i, len(heights) - 1)])
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
