"""HTML building blocks of the report: sections, tables, embedded images, the page.

Every image is embedded as a ``data:`` URI (PNG) and every script inline, so the page is one
self-contained file that opens offline (``file://``) and can be mailed or archived as is.
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

__all__ = [
    "Section",
    "escape",
    "figure_html",
    "image_html",
    "json_for_script",
    "note_html",
    "page_html",
    "png_data_uri",
    "table_html",
]

escape = html.escape


@dataclass
class Section:
    """One section of the report: an anchor id, a title and its HTML body.

    ``status`` is ``"ok"``, ``"warn"`` or ``"missing"`` (shown in the table of contents);
    ``scripts`` are inline JavaScript run after the section's HTML is in the page.
    """

    id: str
    title: str
    body: str
    status: str = "ok"
    scripts: list[str] = field(default_factory=list)


def png_data_uri(image, *, max_size: int | None = None) -> str:
    """A PNG ``data:`` URI of an image file or an array.

    Parameters
    ----------
    image : path-like or (H, W) / (H, W, 3) / (H, W, 4) uint8 array
        An image file (any format PIL reads) or pixels.
    max_size : int, optional
        Longest side in pixels: larger images are shrunk (Lanczos), aspect kept.
    """
    im: Image.Image
    if isinstance(image, (str, os.PathLike)):
        im = Image.open(image)
        im.load()
    else:
        array = np.asarray(image)
        if array.dtype != np.uint8:
            raise TypeError(f"image: expected uint8 pixels, got {array.dtype}")
        im = Image.fromarray(array)
    if im.mode not in ("L", "RGB", "RGBA", "P", "1"):
        im = im.convert("RGB")
    if max_size is not None and max(im.size) > max_size:
        factor = max_size / max(im.size)
        im = im.resize((max(1, round(im.width * factor)), max(1, round(im.height * factor))),
                       Image.Resampling.LANCZOS)
    buffer = io.BytesIO()
    im.save(buffer, format="PNG", optimize=False, compress_level=6)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def figure_png(fig) -> bytes:
    """A matplotlib figure as PNG bytes (the figure is closed)."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=fig.dpi, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def figure_html(fig, caption: str = "", *, width: int | None = None) -> str:
    """A matplotlib figure as an embedded ``<figure>`` (the figure is closed)."""
    uri = "data:image/png;base64," + base64.b64encode(figure_png(fig)).decode("ascii")
    return _figure(uri, caption, width)


def image_html(image, caption: str = "", *, max_size: int | None = None,
               width: int | None = None, pixelated: bool = False) -> str:
    """An image file or uint8 array as an embedded ``<figure>``."""
    return _figure(png_data_uri(image, max_size=max_size), caption, width, pixelated)


def _figure(uri: str, caption: str, width: int | None, pixelated: bool = False) -> str:
    style = f' style="width:{width}px"' if width else ""
    cls = ' class="pixelated"' if pixelated else ""
    cap = f"<figcaption>{escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img src="{uri}" alt="{escape(caption)}"{style}{cls}>{cap}</figure>'


def table_html(rows: Iterable[Sequence], header: Sequence[str], *, caption: str = "") -> str:
    """A table of already formatted cells (str; numbers are formatted with ``str``)."""
    head = "".join(f"<th>{escape(str(h))}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    cap = f"<caption>{escape(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def note_html(text: str, kind: str = "note") -> str:
    """A one-paragraph note (``kind``: ``note``, ``warn`` or ``missing``)."""
    return f'<p class="{kind}">{escape(text)}</p>'


_CSS = """
:root { --fg: #1d2330; --muted: #5b6474; --line: #d8dde6; --accent: #2a62c9; }
* { box-sizing: border-box; }
body { margin: 0; font: 15px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif;
       color: var(--fg); background: #f6f7f9; }
header { background: #1d2330; color: #fff; padding: 18px 28px; }
header h1 { margin: 0 0 4px; font-size: 22px; }
header p { margin: 0; color: #c3c9d4; font-size: 13px; }
nav { padding: 8px 28px; background: #fff; border-bottom: 1px solid var(--line);
      position: sticky; top: 0; z-index: 10; }
nav a { margin-right: 16px; color: var(--accent); text-decoration: none; font-size: 14px; }
nav a.warn::after { content: " ⚠"; color: #b26b00; }
nav a.missing { color: var(--muted); }
main { padding: 8px 28px 40px; max-width: 1400px; }
section { background: #fff; border: 1px solid var(--line); border-radius: 6px;
          margin: 18px 0; padding: 6px 20px 16px; }
h2 { font-size: 19px; margin: 12px 0 8px; }
h3 { font-size: 15px; margin: 16px 0 6px; }
table { border-collapse: collapse; margin: 8px 0 12px; font-size: 13px; }
caption { text-align: left; color: var(--muted); padding-bottom: 4px; }
th, td { border: 1px solid var(--line); padding: 3px 8px; text-align: right; }
th { background: #eef1f5; }
td:first-child, th:first-child { text-align: left; }
figure { display: inline-block; margin: 6px 12px 10px 0; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid var(--line); background: #fff; }
img.pixelated { image-rendering: pixelated; }
figcaption { font-size: 12px; color: var(--muted); max-width: 480px; }
.row { display: flex; flex-wrap: wrap; gap: 6px 10px; align-items: flex-start; }
p.note { color: var(--muted); font-size: 13px; }
p.warn { background: #fff4e0; border-left: 4px solid #e59a00; padding: 6px 10px; }
p.missing { color: var(--muted); font-style: italic; }
.kpi { display: inline-block; margin: 6px 18px 6px 0; }
.kpi b { display: block; font-size: 20px; }
.kpi span { color: var(--muted); font-size: 12px; }
#viewer { width: 100%; height: 640px; border: 1px solid var(--line); }
.controls button { margin: 6px 6px 6px 0; padding: 4px 10px; border: 1px solid var(--line);
                   background: #fff; border-radius: 4px; cursor: pointer; }
.controls button.active { background: var(--accent); color: #fff; border-color: var(--accent); }
footer { color: var(--muted); font-size: 12px; padding: 0 28px 24px; }
"""


def page_html(title: str, subtitle: str, sections: list[Section], *,
              head_scripts: Sequence[str] = (), footer: str = "") -> str:
    """The whole self-contained page.

    Parameters
    ----------
    title, subtitle : str
        Header lines (plain text).
    sections : list of Section
        In page order; each gets an entry in the navigation bar.
    head_scripts : sequence of str
        Inline JavaScript libraries, placed before the sections (e.g. plotly.js).
    footer : str
        Plain text at the bottom.
    """
    nav = "".join(f'<a href="#{s.id}" class="{s.status}">{escape(s.title)}</a>'
                  for s in sections)
    body = "".join(f'<section id="{s.id}"><h2>{escape(s.title)}</h2>{s.body}</section>'
                   for s in sections)
    libs = "".join(f"<script>{_script_safe(js)}</script>" for js in head_scripts)
    scripts = "".join(f"<script>{_script_safe(js)}</script>" for s in sections for js in s.scripts)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>{escape(title)}</title><style>{_CSS}</style>{libs}</head><body>"
        f"<header><h1>{escape(title)}</h1><p>{escape(subtitle)}</p></header>"
        f"<nav>{nav}</nav><main>{body}</main>"
        f"<footer>{escape(footer)}</footer>{scripts}</body></html>\n"
    )


def _script_safe(js: str) -> str:
    """JavaScript that cannot close its ``<script>`` element early nor switch the HTML parser
    into its escaped state (``</script`` in any case, ``<!--``).

    The data embedded in scripts goes through :func:`json_for_script`, which leaves no ``<`` at
    all; this guards the code itself (ours and the vendored library's, which holds neither).
    """
    js = re.sub(r"</(script)", r"<\\/\1", js, flags=re.IGNORECASE)
    return js.replace("<!--", "<\\!--")


def json_for_script(data) -> str:
    """`data` as JSON that is safe inside an HTML ``<script>`` element: ``<``, ``>`` and ``&``
    written as JSON's ``\\u003c``, ``\\u003e``, ``\\u0026`` (the same values once parsed),
    so that no string from an input file (a camera name, say) can end or alter the element."""
    text = json.dumps(data)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def read_text(path: Path) -> str:
    return Path(path).read_text(encoding="utf-8")
