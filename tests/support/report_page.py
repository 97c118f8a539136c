"""Reading ``report.html`` back with :mod:`html.parser` (used by the report tests and the shipped-config runs)."""

from __future__ import annotations

from html.parser import HTMLParser
from pathlib import Path

from hilident.html_report import REPORT_NAME
from hilident.html_report.sections import SECTIONS

SECTION_IDS = [anchor for anchor, _, _ in SECTIONS]


class Page(HTMLParser):
    """The parts of a page the tests look at: tags, attributes, section texts, headings, <pre> texts."""

    def __init__(self, text: str):
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict]] = []
        self.sections: dict[str, str] = {}
        self.headings: dict[str, str] = {}
        self.text_parts: list[str] = []
        self._section: str | None = None
        self._in_h2 = False
        self.feed(text)
        self.close()

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tags.append((tag, attrs))
        if tag == "section":
            self._section = attrs.get("id")
            self.sections[self._section] = ""
            self.headings[self._section] = ""
        self._in_h2 = tag == "h2"

    def handle_endtag(self, tag):
        if tag == "section":
            self._section = None
        if tag == "h2":
            self._in_h2 = False

    def handle_data(self, data):
        self.text_parts.append(data)
        if self._section is not None:
            self.sections[self._section] += data
            if self._in_h2:
                self.headings[self._section] += data

    @property
    def text(self) -> str:
        return "".join(self.text_parts)

    def all(self, tag: str) -> list[dict]:
        return [attrs for t, attrs in self.tags if t == tag]


def check_self_contained(page: Page, css: str = "") -> None:
    """No script, no stylesheet link, no frame; every src a data: URI; every href an anchor or a relative file."""
    for tag in ("script", "link", "iframe", "object", "embed"):
        assert not page.all(tag), tag
    for tag, attrs in page.tags:
        if "src" in attrs:
            assert attrs["src"].startswith("data:image/png;base64,"), (tag, attrs["src"][:40])
        if "href" in attrs:
            href = attrs["href"]
            assert href.startswith("#") or ("://" not in href and not href.startswith(("/", "..", "data:"))), href
    assert "url(" not in css and "@import" not in css


def check_report(folder: Path) -> Page:
    """``folder/report.html`` parsed: every section there under its title, nothing fetched from elsewhere."""
    page = Page((folder / REPORT_NAME).read_text(encoding="utf-8"))
    assert list(page.sections) == SECTION_IDS
    for anchor, title, _ in SECTIONS:
        assert page.headings[anchor].strip() == title
    check_self_contained(page)
    return page
