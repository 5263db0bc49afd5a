"""Benchmark: the HTML report (issue 13) of a processed output directory in headless Chromium.

Usage::

    .venv/bin/python bench/report.py [OUT_DIR] [--repeats 3] [--screenshots docs/img]

Builds ``OUT_DIR/report.html`` with ``nail2nail report OUT_DIR`` (default ``demo-output``, as
``make demo`` writes it; a full-resolution one: ``nail2nail demo --out DIR --report``), then
opens it in headless Chromium (tests/_browser.py: Debian's /usr/bin/chromium, Playwright,
SwiftShader WebGL, offline) `repeats` times, each in a new tab of one browser, and prints the
file size and the median opening time (navigation start → ``nail2nailReport.ready`` resolved),
against a peer opened the same way in the same run: plotly's own minimal page (the full
plotly.min.js of the ``plotly`` package inline, as ``fig.write_html`` embeds it, one scatter3d
of 10 000 points, ``ready`` = ``Plotly.newPlot``'s promise), the cost of loading plotly.js and
drawing a WebGL scene at all. Targets: < 30 MB, < 3 s.

``--screenshots DIR`` saves the page top, the 3D view and the print section as
``DIR/report_{top,viewer,print}.png`` (palette PNGs, ≤ 300 KB each).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from _browser import Browser, unavailable_reason  # noqa: E402

PNG_LIMIT = 300_000


def peer_page(path: Path, n: int = 10_000) -> Path:
    """plotly's minimal offline 3D page with the report's ``ready`` contract."""
    import plotly

    js = (Path(plotly.__file__).parent / "package_data" / "plotly.min.js").read_text()
    rng = np.random.default_rng(0)
    x, y, z = (np.round(v, 4).tolist() for v in rng.normal(size=(3, n)))
    path.write_text(
        "<!DOCTYPE html><html><head><meta charset='utf-8'></head><body>"
        f"<script>{js}</script><div id='viewer' style='width:800px;height:600px'></div><script>"
        f"const t = {{type: 'scatter3d', mode: 'markers', x: {x}, y: {y}, z: {z},"
        " marker: {size: 2}};"
        "window.nail2nailReport = {ready: Plotly.newPlot('viewer', [t])};</script></body></html>"
    )
    return path


def open_times(browser: Browser, page: Path, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        rec = browser.open(page)
        times.append(rec.wait_ready())
        if rec.problems():
            print(f"  {page.name}: {rec.problems()}")
        rec.page.close()
    return times


def save_small_png(src: Path, dst: Path, width: int = 1000) -> int:
    """`src` as a palette PNG no wider than `width`, under PNG_LIMIT bytes; the size."""
    im = Image.open(src).convert("RGB")
    while True:
        if im.width > width:
            im = im.resize((width, round(im.height * width / im.width)), Image.LANCZOS)
        im.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(dst, optimize=True)
        size = dst.stat().st_size
        if size <= PNG_LIMIT:
            return size
        width = int(im.width * 0.85)


def screenshots(browser: Browser, page: Path, out: Path, print_selector: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    rec = browser.open(page)
    rec.wait_ready()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rec.screenshot(tmp / "top.png")
        # element screenshots scroll: a sticky bar would be stamped into the middle of them
        rec.page.add_style_tag(content="nav { position: static !important; }")
        rec.page.locator("#viewer").scroll_into_view_if_needed()
        rec.page.locator("#viewer").screenshot(path=str(tmp / "viewer.png"))
        section = rec.page.locator(print_selector).first
        section.scroll_into_view_if_needed()
        section.screenshot(path=str(tmp / "print.png"))
        for name in ("top", "viewer", "print"):
            dst = out / f"report_{name}.png"
            print(f"  wrote {dst} ({save_small_png(tmp / f'{name}.png', dst) / 1e3:.0f} KB)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", default="demo-output")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--screenshots", type=Path, help="save report_*.png screenshots here")
    parser.add_argument("--print-selector", default="#print",
                        help="CSS selector of the print section (for its screenshot)")
    args = parser.parse_args()
    reason = unavailable_reason()
    if reason:
        sys.exit(f"bench/report.py: {reason}")

    from nail2nail.cli import main as cli

    report = Path(args.out_dir) / "report.html"
    if cli(["report", args.out_dir, "--out", str(report)]) != 0:
        sys.exit(f"nail2nail report {args.out_dir} failed")
    size_mb = report.stat().st_size / 1e6
    with tempfile.TemporaryDirectory() as tmp, Browser() as browser:
        peer = peer_page(Path(tmp) / "plotly_minimal.html")
        open_times(browser, peer, 1)  # warm-up: the browser's first tab, its caches
        t_peer = open_times(browser, peer, args.repeats)
        t_report = open_times(browser, report, args.repeats)
        print(f"report {report}: {size_mb:.2f} MB (target < 30 MB)")
        print(f"open report        {statistics.median(t_report):6.3f} s  (median of "
              f"{args.repeats}: {', '.join(f'{t:.3f}' for t in t_report)}; target < 3 s)")
        print(f"open plotly peer   {statistics.median(t_peer):6.3f} s  (plotly.min.js "
              f"{peer.stat().st_size / 1e6:.1f} MB, scatter3d of 10 000 points)")
        if args.screenshots:
            screenshots(browser, report, args.screenshots, args.print_selector)


if __name__ == "__main__":
    main()
