"""``report.html`` beside ``report.md``: the same text, every figure shown.

Figures are linked by their path relative to the report (``<img src="fig1_phase_plane.png">``): the HTML opened
from its folder shows them, and the output holds each figure once (embedding them doubled the folder's figure
bytes: 7 MB of base64). ``embed=True`` gives one self-contained file instead (base64 PNG). Either way a
figure the report names must exist (:class:`ReportHTMLError` otherwise).

Only the Markdown that the report uses is converted (no runtime dependency beyond the standard library):
ATX headings (with the anchors :func:`heading_anchor` gives, so the summary's links work), GitHub pipe
tables, '-' lists, images ``![alt](file.png)``, paragraphs, and inline ``code``, **bold** and [links](#x).
"""

from __future__ import annotations

import base64
import html
import mimetypes
import os
import re
from pathlib import Path

from .errors import AevOcpError
from .results import write_atomic


class ReportHTMLError(AevOcpError, RuntimeError):
    """The report refers to a figure that does not exist (the message names it)."""


def heading_anchor(heading: str) -> str:
    """The anchor of a Markdown heading as GitHub and report.html spell it (lower case, spaces to '-',
    punctuation other than '-' and '_' dropped)."""
    kept = "".join(ch for ch in heading.strip().lower() if ch.isalnum() or ch in " -_")
    return kept.replace(" ", "-")


_IMG = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")
# link text may hold balanced brackets, as in GitHub's Markdown ("[t ∈ [0, 70]](#…)": a heading's interval)
_LINK = re.compile(r"\[((?:[^\[\]]|\[[^\[\]]*\])+)\]\(([^)\s]+)\)")
_CODE = re.compile(r"`([^`]+)`")
_BOLD = re.compile(r"\*\*(.+?)\*\*")

STYLE = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;line-height:1.45;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:0.85em;display:block;overflow-x:auto}
th,td{border:1px solid #ccc;padding:3px 7px;text-align:left}th{background:#f2f2f2}
img{max-width:100%;display:block;margin:0.8em 0}code{background:#f4f4f4;padding:0 3px}
h1,h2,h3{border-bottom:1px solid #ddd;padding-bottom:0.2em}"""


def _figure_src(base: Path, src: str, embed: bool) -> str:
    """The ``src`` of a figure: its path relative to the report (checked to exist), or a data URI (``embed``)."""
    path = (base / src).resolve()
    if not path.is_file():
        raise ReportHTMLError(f"report.html: the report shows figure {src!r}, but {path} does not exist")
    if not embed:
        return src
    mime = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _inline(text: str, base: Path, embed: bool = False) -> str:
    """Escape HTML, then images (linked, or embedded with ``embed``), code, bold and links."""
    out: list[str] = []
    pos = 0
    for m in _IMG.finditer(text):  # images first: their alt text and path must not be re-parsed
        out.append(_inline_plain(text[pos : m.start()]))
        out.append(f'<img alt="{html.escape(m.group(1))}" src="{html.escape(_figure_src(base, m.group(2), embed))}">')
        pos = m.end()
    out.append(_inline_plain(text[pos:]))
    return "".join(out)


def _inline_plain(text: str) -> str:
    codes: list[str] = []

    def keep(m: re.Match[str]) -> str:
        codes.append(f"<code>{html.escape(m.group(1))}</code>")
        return f"\x00{len(codes) - 1}\x00"

    s = html.escape(_CODE.sub(keep, text), quote=False)
    s = _BOLD.sub(r"<strong>\1</strong>", s)
    s = _LINK.sub(lambda m: f'<a href="{html.escape(m.group(2))}">{m.group(1)}</a>', s)
    return re.sub("\x00(\\d+)\x00", lambda m: codes[int(m.group(1))], s)


def _cells(line: str) -> list[str]:
    body = line.strip()
    body = body[1:] if body.startswith("|") else body
    body = body[:-1] if body.endswith("|") and not body.endswith("\\|") else body
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", body)]


def markdown_to_html(text: str, base: str | os.PathLike[str], title: str = "report", embed: bool = False) -> str:
    """HTML document of the report's Markdown; figures are relative to ``base`` (the HTML's folder), linked there
    (``embed``: read and embedded as data URIs)."""
    root = Path(base)
    inline = lambda t: _inline(t, root, embed)  # noqa: E731
    lines = text.splitlines()
    body: list[str] = []
    para: list[str] = []

    def flush() -> None:
        if para:
            body.append("<p>" + inline(" ".join(para)) + "</p>")
            para.clear()

    i = 0
    while i < len(lines):
        ln = lines[i]
        m = re.match(r"^(#{1,6})\s+(.*)$", ln)
        if m:
            flush()
            level, head = len(m.group(1)), m.group(2).strip()
            body.append(f'<h{level} id="{html.escape(heading_anchor(head))}">{inline(head)}</h{level}>')
        elif ln.lstrip().startswith("|") and i + 1 < len(lines) and re.match(r"^\|?\s*-{3}", lines[i + 1].strip()):
            flush()
            rows = [_cells(ln)]
            i += 2
            while i < len(lines) and lines[i].lstrip().startswith("|"):
                rows.append(_cells(lines[i]))
                i += 1
            head = "".join(f"<th>{inline(c)}</th>" for c in rows[0])
            trs = "".join("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in r) + "</tr>" for r in rows[1:])
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{trs}</tbody></table>")
            continue
        elif re.match(r"^\s*- ", ln):
            flush()
            items = []
            while i < len(lines) and re.match(r"^\s*- ", lines[i]):
                items.append("<li>" + inline(lines[i].split("- ", 1)[1]) + "</li>")
                i += 1
            body.append("<ul>" + "".join(items) + "</ul>")
            continue
        elif not ln.strip():
            flush()
        else:
            para.append(ln.strip())
        i += 1
    flush()
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
        f"<style>{STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n"
    )


#: File endings of the figures a report folder may hold (:func:`unshown_figures`).
FIGURE_SUFFIXES = (".png", ".svg", ".jpg", ".jpeg", ".gif")


def unshown_figures(markdown: str, base: str | os.PathLike[str]) -> list[str]:
    """The figures in the folder ``base`` (top level, by file ending) that ``markdown`` shows nowhere (no
    ``![alt](file)`` names them): a figure a section writes and the report forgets. Sorted names."""
    shown = {Path(m.group(2)).as_posix() for m in _IMG.finditer(markdown)}
    return sorted(
        p.name
        for p in Path(base).iterdir()
        if p.is_file() and p.suffix.lower() in FIGURE_SUFFIXES and p.name not in shown
    )


def write_report_html(
    markdown: str,
    base: str | os.PathLike[str],
    path: str | os.PathLike[str],
    title: str = "report",
    embed: bool = False,
) -> Path:
    """Convert ``markdown`` (figures relative to ``base``, linked; ``embed``: embedded) and write it atomically to
    ``path`` (linked figures: ``path`` belongs in ``base``, so that the links work from the folder)."""
    return write_atomic(path, markdown_to_html(markdown, base, title, embed))
