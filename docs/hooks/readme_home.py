"""mkdocs hook: the site's home page is the repository's README (one source for both).

``docs/index.md`` is a placeholder; its text is replaced, when mkdocs reads it, by README.md
with its ``docs/`` links made relative to the docs folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

README = Path(__file__).resolve().parents[2] / "README.md"


def on_page_read_source(page: Any, config: Any) -> str | None:
    if page.file.src_uri != "index.md":
        return None
    return README.read_text(encoding="utf-8").replace("](docs/", "](")
