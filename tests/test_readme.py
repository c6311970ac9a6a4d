"""The README and the docs/ pages say what holds: their Python examples run as written (each in a
fresh namespace, in a temporary folder), so an example that drifts from the API fails here; their
links between pages resolve, every docs page is linked from the README, the `torchik` commands they
name exist, and they keep no dated runs (those are experiments/*.md's)."""

import argparse
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, *DOCS]
TEXT = {page: page.read_text() for page in PAGES}
EXAMPLES = [(page, code) for page in PAGES for code in re.findall(r"```python\n(.*?)```", TEXT[page], flags=re.S)]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def test_the_readme_has_examples_against_the_root_api():
    assert any(page == README for page, _ in EXAMPLES)
    assert len(EXAMPLES) >= 3
    assert all("import torchik as tk" in code for _, code in EXAMPLES)


@pytest.mark.parametrize("page, code", EXAMPLES,
                         ids=[f"{page.stem}-example{i}" for i, (page, _) in enumerate(EXAMPLES)])
def test_the_readme_example_runs(page, code, tmp_path, monkeypatch, one_thread):
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"{page.name} example", "exec"), {"__name__": "readme_example"})


def test_the_links_between_the_pages_resolve_and_the_readme_links_every_docs_page():
    linked = set()
    for page in PAGES:
        for target in LINK.findall(TEXT[page]):
            if "://" in target or target.startswith("#"):
                continue
            path = (page.parent / target.split("#")[0]).resolve()
            assert path.exists(), f"{page.name} links to {target}, which does not exist"
            if page == README:
                linked.add(path)
    assert DOCS and not set(DOCS) - linked, f"not linked from the README: {sorted(set(DOCS) - linked)}"


def test_the_commands_the_pages_name_exist():
    from torchik.cli import build_parser

    (subcommands,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    named = {name for page in PAGES for name in re.findall(r"^\$? ?torchik ([a-z]+)\b", TEXT[page], flags=re.M)}
    assert {"track", "models", "info", "convert", "live", "replay"} <= named  # the pattern finds them
    assert named <= set(subcommands.choices), named - set(subcommands.choices)


def test_the_readme_is_short_and_the_pages_keep_no_dated_runs():
    assert len(TEXT[README].splitlines()) <= 300
    for page in PAGES:
        dated = re.findall(r"\b20\d\d-\d\d-\d\d\b|\b\d{1,2}:\d\d\b", TEXT[page])
        assert not dated, f"{page.name} has dated runs {dated}: they belong in experiments/*.md"
