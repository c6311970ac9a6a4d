"""The package's layout rule: one idea per module, and a module a reader takes in at once, so at most
400 lines (STYLE: mink's and roma's modules), unless its docstring says why it is longer."""

from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torchik"
MAX_LINES = 400


def test_every_module_is_at_most_400_lines_or_says_why():
    long = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text()
        if len(text.splitlines()) > MAX_LINES and "longer than 400 lines" not in text[:3000]:
            long[str(path.relative_to(PACKAGE))] = len(text.splitlines())
    assert not long, f"modules over {MAX_LINES} lines without a word on why: {long}"
