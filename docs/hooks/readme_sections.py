"""MkDocs hook: a line ``<!-- readme: Section title -->`` in a page is replaced by that ``## Section title``
of the repository's README.md (down to the next ``## `` heading), so the guide pages and the README never
drift apart. The README's own intro (before its first ``## ``) is ``<!-- readme: intro -->``. An unknown
title stops the build (naming it). Links into docs/ are rewritten relative to the site."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

_MARK = re.compile(r"^<!-- readme: (.+?) -->\s*$", re.M)


def _sections(readme: str) -> dict[str, str]:
    parts = re.split(r"^## (.+)$", readme, flags=re.M)
    out = {"intro": parts[0].split("\n", 1)[1] if "\n" in parts[0] else ""}
    for title, body in zip(parts[1::2], parts[2::2]):
        out[title.strip()] = body
    return out


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if "<!-- readme:" not in markdown:
        return markdown
    root = Path(config["config_file_path"]).parent
    sections = _sections((root / "README.md").read_text(encoding="utf-8"))
    depth = page.file.src_uri.count("/")

    def sub(m: re.Match[str]) -> str:
        title = m.group(1).strip()
        if title not in sections:
            raise KeyError(f"{page.file.src_uri}: README.md has no section '## {title}' "
                           f"(sections: {sorted(sections)})")
        body = sections[title].replace("](docs/", "](" + "../" * depth)
        return body if title == "intro" else f"## {title}\n{body}"

    return _MARK.sub(sub, markdown)
