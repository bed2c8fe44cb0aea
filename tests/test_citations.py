"""Every equation, algorithm or figure a module cites is a paper's: the module's docstring names which (paper
A, B or C), and docs/papers.md names each paper once (title, authors) under that letter."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CITATION = re.compile(r"\b(?:eqs?\.|Algorithms?|Fig\.)\s*\d+")
PAPER = re.compile(r"\b[Pp]apers? [ABC]\b")


def test_modules_that_cite_an_equation_name_its_paper() -> None:
    offenders = []
    for path in sorted([*ROOT.glob("common/**/*.py"), *ROOT.glob("services/**/*.py")]):
        text = path.read_text()
        if not CITATION.search(text):
            continue
        docstring = ast.get_docstring(ast.parse(text)) or ""
        if not PAPER.search(docstring):
            offenders.append(path.relative_to(ROOT).as_posix())
    assert offenders == [], "cite the paper in the module docstring (docs/papers.md)"


def test_docs_papers_names_each_paper_once() -> None:
    text = (ROOT / "docs" / "papers.md").read_text()
    for letter in "ABC":
        assert text.count(f'<a id="{letter.lower()}"></a>**{letter}**') == 1
