"""The HTML report (issue 13) opened in a real headless browser: Debian's Chromium driven by
Playwright (tests/_browser.py), offline, through file://.

A small virtual capture (``simulate --scene finger --scale 0.25``, its ideal calibration) goes
through ``process --report``; the page must open without a console error, page error, failed
request or request off its own file, draw its WebGL 3D view, redraw it differently after
``nail2nailReport.rotate(40)`` and after ``colorBy("camera")``. Screenshots go to the test's
tmp dir, and to $NAIL2NAIL_SCREENSHOTS when set. The opening time (navigation start → ``ready``
resolved) is printed (``pytest -s``).

The helper's own checks run on a hand-written WebGL page that follows the report's JavaScript
contract (:data:`CONTRACT_PAGE`), and on broken variants of it, so that "no errors" and "it
drew" cannot pass because the helper saw nothing.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from _browser import Browser, changed_fraction, drawn_fraction, opened, unavailable_reason
from conftest import skip_unless_ci

_REASON = unavailable_reason()


@pytest.fixture(autouse=True)
def _browser_available() -> None:
    """Skip without a headless browser; under CI (NAIL2NAIL_CI) fail instead."""
    if _REASON is not None:
        skip_unless_ci(f"headless browser: {_REASON}")

DRAWN = 0.02  # the 3D view covers at least this fraction of its canvas with non-background
CHANGED = 0.05  # a rotation or a new colouring changes at least this fraction of its pixels

#: A hand-written page with the report's contract: a WebGL canvas in <div id="viewer">, and
#: window.nail2nailReport = {ready, rotate(degrees), colorBy(name)}. A shaded, coloured sphere
#: of triangles; colorBy("camera") paints it in three bands.
CONTRACT_PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>contract</title></head>
<body style="margin:0;background:#fff">
<h1>WebGL contract page</h1>
<div id="viewer"><canvas width="480" height="360"></canvas></div>
<script>
"use strict";
const canvas = document.querySelector("#viewer canvas");
const gl = canvas.getContext("webgl");
const prog = gl.createProgram();
for (const [type, src] of [
  [gl.VERTEX_SHADER, `attribute vec3 p; attribute vec3 c; uniform float a; varying vec3 v;
     void main() { float s = sin(a), k = cos(a);
       vec3 q = vec3(k * p.x + s * p.z, p.y, -s * p.x + k * p.z);
       v = c * (0.4 + 0.6 * max(-q.z, 0.0));
       gl_Position = vec4(q.x * 0.75, q.y, q.z * 0.5, 1.0); }`],
  [gl.FRAGMENT_SHADER, `precision mediump float; varying vec3 v;
     void main() { gl_FragColor = vec4(v, 1.0); }`]]) {
  const sh = gl.createShader(type); gl.shaderSource(sh, src); gl.compileShader(sh);
  gl.attachShader(prog, sh);
}
gl.linkProgram(prog); gl.useProgram(prog); gl.enable(gl.DEPTH_TEST);
const pos = [], n = 24;
const vertex = (i, j) => { const t = Math.PI * i / n, f = 2 * Math.PI * j / n;
  return [Math.sin(t) * Math.cos(f), Math.cos(t), Math.sin(t) * Math.sin(f)]; };
for (let i = 0; i < n; i++) for (let j = 0; j < n; j++)
  for (const [di, dj] of [[0, 0], [1, 0], [1, 1], [0, 0], [1, 1], [0, 1]])
    pos.push(...vertex(i + di, j + dj));
const schemes = {
  albedo: (x, y, z) => [0.9, Math.sin(6 * Math.atan2(z, x)) > 0 ? 0.8 : 0.4, 0.6],
  camera: (x, y, z) => (x > 0.3 ? [0.9, 0.1, 0.1] : x < -0.3 ? [0.1, 0.2, 0.9] : [0.1, 0.8, 0.2]),
  error: (x, y, z) => [0.5 + 0.5 * z, 0.2, 0.5 - 0.5 * z],
};
const buffer = (data, name) => { gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(data), gl.STATIC_DRAW);
  const at = gl.getAttribLocation(prog, name); gl.enableVertexAttribArray(at);
  gl.vertexAttribPointer(at, 3, gl.FLOAT, false, 0, 0); };
buffer(pos, "p");
let angle = 0;
const draw = () => new Promise((resolve) => requestAnimationFrame(() => {
  gl.clearColor(1, 1, 1, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.uniform1f(gl.getUniformLocation(prog, "a"), angle * Math.PI / 180);
  gl.drawArrays(gl.TRIANGLES, 0, pos.length / 3); resolve();
}));
const colorBy = (name) => {
  if (!(name in schemes)) throw new Error("unknown colouring " + name);
  const c = [];
  for (let i = 0; i < pos.length; i += 3) c.push(...schemes[name](pos[i], pos[i + 1], pos[i + 2]));
  buffer(c, "c"); return draw();
};
window.nail2nailReport = {
  ready: colorBy("albedo"),
  rotate: (degrees) => { angle += degrees; return draw(); },
  colorBy,
};
</script>
<p>print section</p>
</body></html>
"""


def screenshot_dirs(tmp_path: Path) -> list[Path]:
    """The test's tmp dir, and $NAIL2NAIL_SCREENSHOTS when set."""
    extra = os.environ.get("NAIL2NAIL_SCREENSHOTS")
    dirs = [tmp_path] + ([Path(extra)] if extra else [])
    for d in dirs:
        d.mkdir(parents=True, exist_ok=True)
    return dirs


def check_report_page(page_path: Path, tmp_path: Path, name: str) -> float:
    """Every browser check of the report's contract on `page_path`; the opening time (s)."""
    shots = tmp_path / f"{name}_shots"
    shots.mkdir()
    with opened(page_path) as page:
        renderer = page.webgl_renderer()
        assert renderer, "this Chromium gives no WebGL (see tests/_browser.py)"
        first = page.viewer_png(shots / "viewer.png")
        assert drawn_fraction(first) > DRAWN, "the 3D view drew nothing but its background"
        page.call("nail2nailReport.rotate(40)")
        rotated = page.viewer_png(shots / "viewer_rotated.png")
        assert changed_fraction(first, rotated) > CHANGED, "rotate(40) left the picture as it was"
        page.call('nail2nailReport.colorBy("camera")')
        by_camera = page.viewer_png(shots / "viewer_camera.png")
        assert changed_fraction(rotated, by_camera) > CHANGED, 'colorBy("camera") changed nothing'
        page.call('nail2nailReport.colorBy("error")')
        page.call('nail2nailReport.colorBy("albedo")')
        page.screenshot(shots / "page.png", full_page=True)
        assert page.problems() == []
        open_s = page.open_s
    for d in screenshot_dirs(tmp_path)[1:]:
        for png in shots.glob("*.png"):
            shutil.copy(png, d / f"{name}_{png.name}")
    print(f"\n{name}: opened in {open_s:.3f} s (navigation start -> ready), WebGL: {renderer}")
    return open_s


def test_contract_page_passes_the_checks(tmp_path):
    page = tmp_path / "contract.html"
    page.write_text(CONTRACT_PAGE)
    check_report_page(page, tmp_path, "contract")


@pytest.mark.parametrize(
    ("change", "caught"),
    [
        ('ready: colorBy("albedo"),', 'ready: colorBy("albedo"), _: console.error("boom"),'),
        ('ready: colorBy("albedo"),', 'ready: colorBy("albedo"), _: setTimeout(() => null.x),'),
        ("<p>print section</p>", '<img src="http://example.invalid/x.png">'),
        ("<p>print section</p>", '<img src="missing.png">'),
    ],
    ids=["console-error", "page-error", "remote-request", "failed-request"],
)
def test_problems_are_caught(tmp_path, change, caught):
    page = tmp_path / "broken.html"
    page.write_text(CONTRACT_PAGE.replace(change, caught))
    with opened(page) as rec:
        rec.page.wait_for_timeout(200)
        assert rec.problems(), "the helper saw nothing wrong on a broken page"


def test_blank_and_frozen_views_are_caught(tmp_path):
    blank = CONTRACT_PAGE.replace("gl.drawArrays(", "0 && gl.drawArrays(")
    frozen = CONTRACT_PAGE.replace("angle += degrees;", "").replace('buffer(c, "c");', "")
    (tmp_path / "blank.html").write_text(blank)
    (tmp_path / "frozen.html").write_text(frozen)
    with Browser() as browser:
        rec = browser.open(tmp_path / "blank.html")
        rec.wait_ready()
        assert drawn_fraction(rec.viewer_png(tmp_path / "blank.png")) < DRAWN
        rec = browser.open(tmp_path / "frozen.html")
        rec.wait_ready()
        first = rec.viewer_png(tmp_path / "frozen.png")
        rec.call("nail2nailReport.rotate(40)")
        rec.call('nail2nailReport.colorBy("camera")')
        assert changed_fraction(first, rec.viewer_png(tmp_path / "frozen2.png")) < CHANGED


def test_report_opens_draws_rotates_and_recolours(processed_finger, tmp_path):
    """``process --report`` of a small virtual finger (tests/conftest.py)."""
    report = processed_finger / "report.html"
    open_s = check_report_page(report, tmp_path, "report")
    print(f"report: {report.stat().st_size / 1e6:.2f} MB")
    assert open_s < 30  # a sanity bound for a loaded CI machine; bench/report.py measures it
