"""The README's Python example runs as printed, and prints the figures the README quotes.

About 45 s on 2 cores (the full default test bench generated, then the physics identified): marked
slow (make test-slow).
"""

from __future__ import annotations

import ast
import re

import pytest

from conftest import ROOT

README = ROOT / "README.md"


@pytest.mark.slow
def test_the_readme_example_prints_what_the_readme_says(hypa_cache, capsys) -> None:
    text = README.read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.DOTALL | re.MULTILINE)
    assert len(blocks) == 1, f"README.md: {len(blocks)} python blocks, expected the one example"
    assert len(blocks[0].strip().splitlines()) <= 16  # the first page's example stays short
    exec(compile(blocks[0], "README.md, the python example", "exec"), {"__name__": "readme"})  # noqa: S102
    printed = capsys.readouterr().out.strip().splitlines()
    quoted = ast.literal_eval(re.search(r"`(\{'yaw_rate': [^`]+\})`", text).group(1))
    assert ast.literal_eval(printed[-1]) == pytest.approx(quoted, abs=0.01)
    share = re.search(r"output error \d+ % → ([\d.]+) % of the variance", text)
    assert share is not None and share.group(1) in "\n".join(printed[:-1])
