"""Functions of both packages stay under 60 lines of code, so each reads on one screen."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_CODE_LINES = 60


def code_lines(lines: list[str], node: ast.AST) -> int:
    """Lines of ``node`` that hold code: not blank, not a comment, not its docstring."""
    body = getattr(node, "body", [])
    doc = range(0)
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        doc = range(body[0].lineno, body[0].end_lineno + 1)
    return sum(1 for number in range(node.lineno, node.end_lineno + 1)
               if number not in doc and lines[number - 1].strip()
               and not lines[number - 1].strip().startswith("#"))


def long_functions(folder: Path) -> list[str]:
    """``path:function (N lines)`` for every function of ``folder`` over :data:`MAX_CODE_LINES`."""
    out = []
    for path in sorted(folder.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = code_lines(lines, node)
                if n > MAX_CODE_LINES:
                    out.append(f"{path.relative_to(ROOT)}:{node.name} ({n} lines)")
    return out


def test_line_count_leaves_out_docstring_comments_and_blank_lines():
    text = 'def f():\n    """Doc.\n\n    More.\n    """\n    # note\n\n    x = 1\n    return x\n'
    node = ast.parse(text).body[0]
    assert code_lines(text.splitlines(), node) == 3


@pytest.mark.slow
def test_no_function_of_ifmi_or_omnisim_is_over_60_lines():
    found = long_functions(ROOT / "ifmi") + long_functions(ROOT / "omnisim")
    assert not found, "functions over 60 lines of code: " + ", ".join(found)
