"""No function of jaxmpm or calibration over 60 lines and no module over 400 lines, except where a
comment says why: `# longer than 60 lines on purpose: <why>` between the function's `def` and its
first statement (after the docstring), `# longer than 400 lines on purpose: <why>` between the top of
the module and its first statement (after the docstring). Lengths count every line, docstrings,
comments and blank lines included: a function from its `def` to its last line, a module whole."""

import ast
import re
from pathlib import Path

import calibration
import jaxmpm

FUNCTION_LINES, MODULE_LINES = 60, 400
SOURCES = [Path(p) for package in (jaxmpm, calibration) for p in package.__path__]
ROOT = Path(jaxmpm.__file__).parents[1]  # names are given from here: jaxmpm/..., calibration/...


def _reason(lines: list[str], limit: int) -> bool:
    """Whether a comment among `lines` says why the code is longer than `limit` lines."""
    pattern = re.compile(rf"^\s*#.*longer than {limit} lines on purpose: \S")
    return any(pattern.match(line) for line in lines)


def _first_statement(body: list[ast.stmt], end: int) -> int:
    """The line of the first statement of `body` after its docstring (end + 1 where there is none)."""
    docstring = isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
    rest = body[1:] if docstring else body
    return rest[0].lineno if rest else end + 1


def unexplained_lengths(source: str, name: str) -> list[str]:
    """The module `name` (its text `source`) if it is over MODULE_LINES lines, and each of its
    functions (methods and nested functions included) over FUNCTION_LINES lines, that lack the
    comment saying why."""
    lines = source.splitlines()
    tree = ast.parse(source)
    found = []
    if len(lines) > MODULE_LINES and not (
        tree.body and _reason(lines[: _first_statement(tree.body, len(lines)) - 1], MODULE_LINES)
    ):
        found.append(f"{name}: {len(lines)} lines")
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = node.end_lineno - node.lineno + 1
            header = lines[node.lineno - 1 : _first_statement(node.body, node.end_lineno) - 1]
            if length > FUNCTION_LINES and not _reason(header, FUNCTION_LINES):
                found.append(f"{name}:{node.lineno} {node.name}: {length} lines")
    return found


def test_the_check_finds_a_long_function_or_module_without_a_reason():
    body = "".join(f"    x{i} = {i}\n" for i in range(FUNCTION_LINES))
    bare = f'def f():\n    """Doc."""\n{body}'
    explained = f'def f():\n    """Doc."""\n    # longer than {FUNCTION_LINES} lines on purpose: a test\n{body}'
    late = f'def f():\n    """Doc."""\n{body}    # longer than {FUNCTION_LINES} lines on purpose: too late\n'
    assert unexplained_lengths(bare, "m") == [f"m:1 f: {FUNCTION_LINES + 2} lines"]
    assert unexplained_lengths(explained, "m") == []
    assert unexplained_lengths(late, "m") == [f"m:1 f: {FUNCTION_LINES + 2} lines"]  # a comment after the code
    assert unexplained_lengths("def g():\n    pass\n" * 30, "m") == []
    module = '"""Doc."""\n' + "x = 1\n" * MODULE_LINES
    assert unexplained_lengths(module, "m") == [f"m: {MODULE_LINES + 1} lines"]
    reason = f"# longer than {MODULE_LINES} lines on purpose: a test\n"
    assert unexplained_lengths('"""Doc."""\n' + reason + "x = 1\n" * MODULE_LINES, "m") == []


def test_every_long_function_and_module_says_why():
    files = sorted(path for root in SOURCES for path in root.rglob("*.py"))
    assert len(files) > 60, f"only {len(files)} modules found: the walk over the packages is broken"
    found = [item for path in files for item in unexplained_lengths(path.read_text(), str(path.relative_to(ROOT)))]
    assert not found, (
        f"{len(found)} over the length limits without a comment saying why "
        f"('# longer than {FUNCTION_LINES} lines on purpose: ...' or '# longer than {MODULE_LINES} lines on "
        "purpose: ...' after the docstring; or split them):\n" + "\n".join(found)
    )
