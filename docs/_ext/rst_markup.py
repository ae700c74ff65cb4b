"""A griffe extension for the API reference: the reStructuredText bits of fitstiff's docstrings
in Markdown, so that they render (and ``mkdocs build --strict`` does not read ``x["force"]`` in a
doctest as a link).

The docstrings are Google style (``Args:``, ``Returns:``, ``Raises:``) with some reST inside,
which mkdocstrings would show as plain text; before parsing, this rewrites

- Sphinx roles (``:func:`fit```, ``:class:`~fitstiff.io.log.Log```, ``:mod:`text <target>```)
  as optional cross-references: a link where the target is in the reference, the name in code
  where it is not (private or outside fitstiff: no warning);
- doctest blocks (``>>>`` paragraphs) and literal blocks (``text::`` then an indented block) as
  fenced code;
- simple tables (``====  ====`` borders) as Markdown tables;

and drops doctest directives (``# doctest: +SKIP``).

Google sections that hold examples (``Example:``) are left to griffe. Nothing in ``fitstiff/``
is imported or changed; mkdocs.yml loads this file by path (``extensions:``).
"""

from __future__ import annotations

import html
import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:func|class|meth|attr|mod|data|exc|obj|const|type):`([^`]+)`")
#: a role whose target the line wraps: joined onto one line first
_WRAPPED_ROLE = re.compile(r"(:(?:py:)?[a-z]+:`[^`\n]*)\n[ \t]*([^`\n]*`)")
#: a doctest directive at the end of a ``>>>`` or ``...`` line (not for readers)
_DIRECTIVE = re.compile(r"^(\s*(?:>>>|\.\.\.).*?)\s+#\s*doctest:.*$", re.MULTILINE)
_TITLED = re.compile(r"^(.*?)\s*<([^<>]+)>$")
_BORDER = re.compile(r"^(\s*)(=+)(\s+=+)+\s*$")
_SECTION = re.compile(
    r"^(Args|Arguments|Parameters|Params|Keyword Args|Keyword Arguments|Other Parameters|"
    r"Returns?|Yields?|Receives?|Raises|Warns|Warnings?|Attributes|Functions|Methods|Classes|"
    r"Modules|Examples?|Notes?|Todo|References?|See Also):\s*$")
_EXAMPLES = {"Example", "Examples"}


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def _target(obj: griffe.Object, target: str) -> str:
    """The full path of a role's target, seen from the object whose docstring holds it."""
    target = target.lstrip("~!.")
    head, _, rest = target.partition(".")
    try:
        full = obj.resolve(head)
    except Exception:  # noqa: BLE001 - unknown to griffe: left as written (an optional ref)
        return target
    return f"{full}.{rest}" if rest else full


def _role(obj: griffe.Object, match: re.Match) -> str:
    text = match[1].strip()
    titled = _TITLED.match(text)
    if titled:
        title, target = titled[1], titled[2]
    else:
        target = text
        title = target.lstrip("~!.").rsplit(".", 1)[-1] if target.startswith("~") else \
            target.lstrip("!.")
    identifier = html.escape(_target(obj, target), quote=True)
    return f'<autoref identifier="{identifier}" optional><code>{html.escape(title)}</code></autoref>'


def _table(lines: list[str]) -> list[str]:
    """A reST simple table (from its first border to its last) as Markdown table lines."""
    pad = _indent(lines[0])
    spans = [m.start() for m in re.finditer(r"=+", lines[0])]
    borders = [k for k, line in enumerate(lines) if _BORDER.match(line)]
    rows: list[list[str]] = []
    for line in lines[1:-1]:
        if _BORDER.match(line):
            rows.append([])                        # the header's end: marks where the body starts
            continue
        if not line.strip():
            continue
        cuts = []
        for b in spans[1:]:                        # text may run past a column's border
            if b < len(line) and line[b - 1] != " ":
                b = line.find(" ", b)
                b = len(line) if b < 0 else b
            cuts.append(max(b, cuts[-1] if cuts else 0))
        cells = [line[a:b].strip() for a, b in zip([spans[0], *cuts], [*cuts, len(line)])]
        if cells[0] or not rows or not rows[-1]:
            rows.append(cells)
        else:                                      # a continuation: its first column is blank
            rows[-1] = [f"{a} {b}".strip() for a, b in zip(rows[-1], cells)]
    if len(borders) == 3:
        cut = rows.index([])
        head = [" ".join(col).strip() for col in zip(*rows[:cut])]
        body = rows[cut + 1:]
    else:                                          # no header row: an empty one
        head, body = [""] * len(spans), rows

    def cell(text: str) -> str:                  # a "|" splits a row, except in code
        parts = re.split(r"(``.*?``|`[^`]*`)", text)
        return "".join(p if k % 2 else p.replace("|", r"\|") for k, p in enumerate(parts))

    def row(cells: list[str]) -> str:
        return " " * pad + "| " + " | ".join(map(cell, cells)) + " |"

    return ["", row(head), " " * pad + "|" + "---|" * len(spans), *map(row, body), ""]


def _table_end(lines: list[str], start: int) -> int:
    """Index just past the simple table whose top border is ``lines[start]``: the border after
    which a blank line (or the end) follows, or the third one."""
    pad = _indent(lines[start])
    seen = 1
    for i in range(start + 1, len(lines)):
        if _BORDER.match(lines[i]) and _indent(lines[i]) == pad:
            seen += 1
            if seen == 3 or i + 1 == len(lines) or not lines[i + 1].strip():
                return i + 1
    return len(lines)


def to_markdown(text: str, obj: griffe.Object) -> str:
    text = _DIRECTIVE.sub(r"\1", _WRAPPED_ROLE.sub(r"\1 \2", text))
    lines = text.split("\n")
    out: list[str] = []
    section: str | None = None
    i = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        ind = _indent(line)
        if ind == 0 and _SECTION.match(line):
            section = line.strip()[:-1]
            out.append(line)
            i += 1
            continue
        if ind == 0 and stripped and section is not None:
            section = None
        examples = section in _EXAMPLES

        if stripped.startswith("```"):                          # Markdown fence: as it is
            out.append(line)
            i += 1
            while i < len(lines):
                out.append(lines[i])
                i += 1
                if lines[i - 1].strip().startswith("```"):
                    break
            continue
        if _BORDER.match(line):
            end = _table_end(lines, i)
            out += [_ROLE.sub(lambda m: _role(obj, m), t) for t in _table(lines[i:end])]
            i = end
            continue
        if stripped.startswith(">>>") and not examples:         # doctest block
            block = []
            while i < len(lines) and lines[i].strip():
                block.append(lines[i][ind:] if _indent(lines[i]) >= ind else lines[i].lstrip())
                i += 1
            pad = " " * ind
            out += [pad + "```pycon", *(pad + b for b in block), pad + "```"]
            continue
        if stripped.endswith("::") and not examples:            # literal block
            j = i + 1
            while j < len(lines) and not lines[j].strip():
                j += 1
            if j < len(lines) and _indent(lines[j]) > ind:
                if _SECTION.match(stripped[:-1]):               # "Example::": a Google section
                    out.append(line[:-1])
                    section = stripped[:-2] if ind == 0 else section
                    i += 1
                    continue
                lead = line.rstrip()[:-2].rstrip()
                if lead and not line.rstrip()[:-2].endswith(" "):
                    lead += ":"
                if lead.strip():
                    out.append(_ROLE.sub(lambda m: _role(obj, m), lead))
                block = []
                k = j
                while k < len(lines) and (not lines[k].strip() or _indent(lines[k]) > ind):
                    block.append(lines[k])
                    k += 1
                while block and not block[-1].strip():
                    block.pop()
                inner = min(_indent(b) for b in block if b.strip())
                pad = " " * ind
                lang = "pycon" if block[0].strip().startswith(">>>") else ""
                out += ["", pad + "```" + lang, *(pad + b[inner:] for b in block), pad + "```", ""]
                i = k
                continue
        out.append(_ROLE.sub(lambda m: _role(obj, m), line))
        i += 1
    return "\n".join(out)


class RstMarkup(griffe.Extension):
    """Rewrites every docstring of a loaded package (see the module docstring)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        stack: list[griffe.Object] = [pkg]
        while stack:
            obj = stack.pop()
            if obj.docstring is not None:
                obj.docstring.value = to_markdown(obj.docstring.value, obj)
            stack.extend(m for m in obj.members.values() if not m.is_alias)
