"""Headless Chromium for the tests (and bench/report.py) that open the HTML report (issue 13).

The browser is Debian's ``chromium`` (/usr/bin/chromium), installed by ``make test`` where
apt-get is usable; it is driven by Python ``playwright`` (the ``test`` extra) with
``executable_path`` set, so Playwright never downloads a browser of its own (the network is
closed). :func:`unavailable_reason` says why a browser test must skip.

WebGL without a GPU: Chromium's headless mode (``--headless``, the new headless) picks ANGLE on
SwiftShader, the CPU Vulkan bundled with Debian's package (/usr/lib/chromium/libvk_swiftshader.so),
for WebGL by itself (``--use-angle=swiftshader-webgl`` appears on its command line), so
``--disable-gpu`` does not take WebGL away: measured here (Chromium 156), WebGL 2 draws on
"ANGLE (Google, Vulkan 1.3.0 (SwiftShader Device (Subzero)))" with or without --disable-gpu, and
with or without ``--enable-unsafe-swiftshader``. That last flag is the opt-in that Chrome 137+
asks for before it falls back to SwiftShader for WebGL outside headless mode; Playwright passes
it by default and :data:`ARGS` names it too, so that a change of the headless default cannot
silently take the 3D view away. :meth:`ReportPage.webgl_renderer` reports what drew.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

CHROMIUM = Path(os.environ.get("NAIL2NAIL_CHROMIUM", "/usr/bin/chromium"))

#: The flags this project's machines start Chromium with (.library's polyglot notes): without
#: the background-networking ones Chromium keeps trying the closed network. --disable-gpu only
#: turns off the (absent) GPU; WebGL stays on SwiftShader (module docstring).
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-unsafe-swiftshader",
]

#: Records when the report's ``ready`` promise resolves (``performance.now()``: ms since the
#: navigation started), whenever the page assigns ``window.nail2nailReport``: installed before
#: any script of the page runs.
_READY_PROBE = """
(() => {
  let report;
  Object.defineProperty(window, "nail2nailReport", {
    configurable: true,
    get() { return report; },
    set(value) {
      report = value;
      if (value && value.ready && typeof value.ready.then === "function") {
        value.ready.then(
          () => { window.__nail2nailReadyMs = performance.now(); },
          (e) => { window.__nail2nailReadyError = String(e && e.stack || e); });
      }
    },
  });
})();
"""

_WEBGL_RENDERER = """() => {
  const gl = document.createElement("canvas").getContext("webgl2")
      || document.createElement("canvas").getContext("webgl");
  if (!gl) return null;
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  return info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
}"""

#: The largest canvas in the 3D view (plotly's WebGL scene), as a clip rectangle.
_VIEWER_CANVAS_BOX = """() => {
  const canvases = [...document.querySelectorAll("#viewer canvas")];
  if (!canvases.length) return null;
  const area = (c) => { const r = c.getBoundingClientRect(); return r.width * r.height; };
  const c = canvases.reduce((a, b) => (area(b) > area(a) ? b : a));
  c.scrollIntoView({block: "center"});
  const r = c.getBoundingClientRect();
  return {x: r.x, y: r.y, width: r.width, height: r.height};
}"""


def unavailable_reason() -> str | None:
    """Why the headless-browser tests cannot run here, or ``None`` when they can."""
    if not CHROMIUM.exists():
        return (
            f"{CHROMIUM} is absent: Debian's chromium is installed by `make test` where apt-get "
            "is usable (root or password-less sudo); install it with `apt-get install "
            "chromium`"
        )
    if importlib.util.find_spec("playwright") is None:
        return "Python playwright is not installed (the `test` extra: pip install -e '.[test]')"
    return None


@dataclass
class ReportPage:
    """A page opened in headless Chromium, with what went wrong while it ran."""

    page: object
    url: str
    console_errors: list[str] = field(default_factory=list)
    page_errors: list[str] = field(default_factory=list)
    failed_requests: list[str] = field(default_factory=list)
    remote_requests: list[str] = field(default_factory=list)
    open_s: float | None = None  # navigation start -> `ready` resolved

    def problems(self) -> list[str]:
        """Every console error, page error, failed request and non-local request so far."""
        return (
            [f"console error: {m}" for m in self.console_errors]
            + [f"page error: {m}" for m in self.page_errors]
            + [f"failed request: {m}" for m in self.failed_requests]
            + [f"request off the page's file: {m}" for m in self.remote_requests]
        )

    def webgl_renderer(self) -> str | None:
        """The WebGL renderer this browser gives a new canvas (``None``: no WebGL)."""
        return self.page.evaluate(_WEBGL_RENDERER)

    def wait_ready(self, timeout_s: float = 60.0) -> float:
        """Wait for ``window.nail2nailReport.ready``; the opening time (s) since navigation."""
        self.page.wait_for_function(
            "() => window.__nail2nailReadyMs !== undefined || window.__nail2nailReadyError",
            timeout=timeout_s * 1000,
        )
        error = self.page.evaluate("() => window.__nail2nailReadyError")
        if error:
            raise AssertionError(f"nail2nailReport.ready rejected: {error}")
        self.open_s = self.page.evaluate("() => window.__nail2nailReadyMs") / 1000
        return self.open_s

    def call(self, expression: str) -> object:
        """Evaluate `expression` (e.g. ``nail2nailReport.rotate(40)``), awaiting its promise."""
        return self.page.evaluate(f"async () => await window.{expression}")

    def viewer_png(self, path: Path) -> np.ndarray:
        """Screenshot of the 3D view's WebGL canvas to `path`; its RGB pixels."""
        box = self.page.evaluate(_VIEWER_CANVAS_BOX)
        if box is None:
            raise AssertionError("no canvas inside <div id='viewer'>")
        self.page.screenshot(path=str(path), clip=box)
        return np.asarray(Image.open(path).convert("RGB"))

    def screenshot(self, path: Path, full_page: bool = False) -> None:
        self.page.screenshot(path=str(path), full_page=full_page)


class Browser:
    """Headless Chromium with a new empty profile; ``with Browser() as b: b.open(path)``."""

    def __init__(self, width: int = 1200, height: int = 900):
        self.viewport = {"width": width, "height": height}

    def __enter__(self) -> Browser:
        from playwright.sync_api import sync_playwright

        self._stack = contextlib.ExitStack()
        profile = self._stack.enter_context(tempfile.TemporaryDirectory(prefix="n2n-chromium-"))
        self._playwright = self._stack.enter_context(sync_playwright())
        self.context = self._playwright.chromium.launch_persistent_context(
            profile,
            executable_path=str(CHROMIUM),
            headless=True,
            args=ARGS,
            viewport=self.viewport,
        )
        self._stack.callback(self.context.close)
        return self

    def __exit__(self, *exc) -> None:
        self._stack.close()

    def open(self, target: Path | str, timeout_s: float = 60.0) -> ReportPage:
        """Open a file (file://) or URL in a new tab, recording errors and off-file requests."""
        url = Path(target).resolve().as_uri() if isinstance(target, Path) else target
        page = self.context.new_page()
        rec = ReportPage(page, url)
        page.on("console", lambda m: m.type == "error" and rec.console_errors.append(m.text))
        page.on("pageerror", lambda e: rec.page_errors.append(str(e)))
        page.on("requestfailed", lambda r: rec.failed_requests.append(f"{r.url} {r.failure}"))
        page.on(
            "request",
            lambda r: r.url.startswith(("file:", "data:", "blob:", "about:"))
            or rec.remote_requests.append(r.url),
        )
        page.add_init_script(_READY_PROBE)
        page.goto(url, wait_until="load", timeout=timeout_s * 1000)
        return rec


@contextlib.contextmanager
def opened(target: Path | str, timeout_s: float = 60.0) -> Iterator[ReportPage]:
    """One page of a new browser, opened and ``ready``."""
    with Browser() as browser:
        rec = browser.open(target, timeout_s)
        rec.wait_ready(timeout_s)
        yield rec


def drawn_fraction(pixels: np.ndarray, tolerance: int = 12) -> float:
    """Fraction of pixels that differ from the background (the most common colour of the
    image's border) by more than `tolerance` in some channel."""
    border = np.concatenate([pixels[0], pixels[-1], pixels[:, 0], pixels[:, -1]])
    colours, counts = np.unique(border.reshape(-1, 3), axis=0, return_counts=True)
    background = colours[np.argmax(counts)].astype(int)
    return float(np.mean(np.abs(pixels.astype(int) - background).max(axis=2) > tolerance))


def changed_fraction(a: np.ndarray, b: np.ndarray, tolerance: int = 12) -> float:
    """Fraction of pixels that differ between two screenshots of the same size."""
    if a.shape != b.shape:
        return 1.0
    return float(np.mean(np.abs(a.astype(int) - b.astype(int)).max(axis=2) > tolerance))
