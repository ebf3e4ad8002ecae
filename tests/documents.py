"""The README and the docs pages as the tests read them: sections, code blocks and tables."""

import re
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DOCS = REPO / "docs"


def read(page: str) -> str:
    """The text of ``README.md`` or of the docs page ``page`` (e.g. ``command-line.md``)."""
    return (REPO / page if page == "README.md" else DOCS / page).read_text()


def headings(text: str) -> list[tuple[int, int, int, str]]:
    """Every markdown heading of ``text`` outside code blocks: (start, end, level, title)."""
    found, fenced, position = [], False, 0
    for line in text.splitlines(keepends=True):
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and (match := re.match(r"(#+) (.*)", line)):
            found.append((position, position + len(line), len(match.group(1)), match.group(2).strip()))
        position += len(line)
    return found


def section(page: str, title: str) -> str:
    """The part of ``page`` under the heading ``title`` (any level), up to the next heading of the same
    level or above."""
    text = read(page)
    marks = headings(text)
    index = next((i for i, mark in enumerate(marks) if mark[3] == title), None)
    assert index is not None, f"{page} has no heading {title!r}"
    _, start, level, _ = marks[index]
    end = next((mark[0] for mark in marks[index + 1 :] if mark[2] <= level), len(text))
    return text[start:end]


def code_blocks(text: str, language: str) -> list[str]:
    """The fenced code blocks of ``language`` in ``text``."""
    return re.findall(rf"^```{language}\n(.*?)^```", text, re.S | re.M)


def code(page: str, title: str, language: str = "python") -> str:
    """The first ``language`` block of ``page``'s section ``title``."""
    return code_blocks(section(page, title), language)[0]


def commands(page: str, title: str) -> list[str]:
    """The command lines of the first bash block of ``page``'s section ``title`` (comments dropped)."""
    return [line.split("  #")[0].strip() for line in code(page, title, "bash").splitlines() if line.strip()]


def markdown_tables(text: str) -> list[list[dict[str, str]]]:
    """Every markdown table of ``text`` (a block between blank lines) as rows of {header: cell}."""

    def cells(line: str) -> list[str]:
        return [cell.strip() for cell in line.strip().strip("|").split("|")]

    tables = []
    for block in text.split("\n\n"):
        lines = block.strip().splitlines()
        if len(lines) >= 3 and lines[0].startswith("|") and set(lines[1]) <= set("|-: "):
            header = cells(lines[0])
            tables.append([dict(zip(header, cells(line), strict=True)) for line in lines[2:]])
    return tables


def prose(text: str) -> str:
    """``text`` with its fenced code blocks emptied (their lines kept, blank)."""
    return re.sub(r"^```.*?^```", lambda block: "\n" * block.group().count("\n"), text, flags=re.S | re.M)


def blocks(page: str) -> list[tuple[str, str]]:
    """The prose blocks of ``page`` (paragraphs, lists, tables: text between blank lines, code blocks
    left out), each with the title of the heading it sits under ("" before the first)."""
    found, title = [], ""
    for block in re.split(r"\n[ \t]*\n", prose(read(page))):
        for line in block.strip().splitlines():
            if match := re.match(r"(#+) (.*)", line):
                title = match.group(2).strip()
        if block.strip():
            found.append((title, block.strip()))
    return found
