"""mkdocs hook: the pages read the same on GitHub and on the site.

GitHub needs a pipe inside a table cell's code span escaped (``\\|``) and shows it as ``|``;
Python-Markdown keeps the backslash there (it already ignores pipes inside code spans). So in
table rows, ``\\|`` inside a code span becomes ``|`` before the page is rendered.
"""

import re

_CODE = re.compile(r"(`+)(.+?)\1")


def _unescape_code(match: re.Match) -> str:
    return match.group(1) + match.group(2).replace("\\|", "|") + match.group(1)


def on_page_markdown(markdown: str, **kwargs) -> str:
    lines, fenced = [], False
    for line in markdown.split("\n"):
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced and line.lstrip().startswith("|"):
            line = _CODE.sub(_unescape_code, line)
        lines.append(line)
    return "\n".join(lines)
