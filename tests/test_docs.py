"""The repository's texts speak about csb, not about how it was developed: the documents (README,
docs/, papers/) name no development milestone and link nothing outside the repository, and the
comments, docstrings and strings of the sources (python/csb, src, validation, tests, scripts, the
scenes and the build files) name no milestone either. A milestone is the word "issue" or "stop"
followed by a number (optionally "#", optionally across a line break), so "stop" as a verb is not
flagged. Names in code say what a thing is, not the step that made it: an identifier holding
"issue" or "stop" glued to a number (`issue7`, `PARTS_ISSUE7`, `kStop15`) is flagged in code
and prose alike. These tests read the checkout, not the installed package."""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

MILESTONE = re.compile(r"\b(?:issue|stop)s?(?:[ \t]*\n)?[ \t*]*#?[0-9]+\b", re.IGNORECASE)
LINK = re.compile(r"\bhttps?://", re.IGNORECASE)
# "issue"/"stop" starting a word, after an underscore or as a camelCase part, then an optional
# underscore and a number: a name built from a milestone.
IDENTIFIER = re.compile(r"(?:(?<![A-Za-z])(?i:issue|stop)|(?<=[a-z0-9])(?:Issue|Stop))_?[0-9]+")

DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md"), *(ROOT / "papers").glob("*.md")])
PYTHON = sorted(p for p in [*(ROOT / "python" / "csb").rglob("*.py"), *(ROOT / "python" / "csb").rglob("*.pyi"),
                            *(ROOT / "validation").rglob("*.py"), *(ROOT / "tests").glob("*.py"),
                            *(ROOT / "scripts").glob("*.py")]
                if p.resolve() != Path(__file__).resolve())  # this file has to spell the pattern out
CPP = sorted(p for p in [*(ROOT / "src").rglob("*"), *(ROOT / "examples").rglob("*")]
             if p.suffix in (".hpp", ".cpp", ".h", ".vert", ".frag") or p.name.endswith(".cpp.in"))
WHOLE = sorted([ROOT / "dev", ROOT / "pyproject.toml", ROOT / "CMakeLists.txt", *(ROOT / "src").rglob("CMakeLists.txt"),
                *(ROOT / "examples").rglob("CMakeLists.txt"), *(ROOT / "cmake").glob("*"),
                *(ROOT / "python" / "csb" / "scenes").glob("*.toml"), *(ROOT / "scripts").glob("*.sh")])


def python_prose(source: str) -> str:
    """`source` with everything but its comments (without the '#') and string literals (docstrings,
    help text) blanked to spaces; line breaks kept, so offsets give line numbers."""
    lines = source.splitlines(keepends=True)
    out = [[" " if ch not in "\r\n" else ch for ch in line] for line in lines]
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            keep = tok.string[1:]
            (row, col), offset = tok.start, 1
        elif tok.type == tokenize.STRING or tok.type == getattr(tokenize, "FSTRING_MIDDLE", -1):
            keep = tok.string
            (row, col), offset = tok.start, 0
        else:
            continue
        for ch in keep:  # a string may span lines
            if ch == "\n":
                row, col, offset = row + 1, 0, 0
                continue
            if col + offset < len(out[row - 1]):  # (an f-string's parts may be shorter than their source)
                out[row - 1][col + offset] = ch
            col += 1
    return "".join("".join(line) for line in out)


def cpp_prose(source: str) -> str:
    """`source` with everything but its comments (without their delimiters) and string literals
    blanked to spaces; line breaks kept."""
    out = []
    i, n = 0, len(source)

    def blank(text: str) -> str:
        return "".join(ch if ch == "\n" else " " for ch in text)

    while i < n:
        if source.startswith("//", i):
            j = source.find("\n", i)
            j = n if j < 0 else j
            out.append("  " + source[i + 2:j])
        elif source.startswith("/*", i):
            j = source.find("*/", i + 2)
            j = n if j < 0 else j
            out.append("  " + source[i + 2:j] + blank(source[j:j + 2]))
            j += 2
        elif source.startswith('R"', i) and (i == 0 or not (source[i - 1].isalnum() or source[i - 1] == "_")):
            delim = source[i + 2:source.find("(", i + 2)]
            j = source.find(")" + delim + '"', i)
            j = n if j < 0 else j + len(delim) + 2
            out.append(source[i:j])
        elif source[i] in "\"'":
            j = i + 1
            while j < n and source[j] != source[i] and source[j] != "\n":
                j += 2 if source[j] == "\\" else 1
            j = min(j + 1, n)
            out.append(source[i:j])
        else:
            out.append(blank(source[i]))
            j = i + 1
        i = j
    return "".join(out)


def offences(pattern: re.Pattern[str], text: str, original: str, path: Path) -> list[str]:
    found = []
    for m in pattern.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        found.append(f"{path.relative_to(ROOT)}:{line}: {original.splitlines()[line - 1].strip()}")
    return found


def test_the_scanners_keep_prose_and_drop_code():
    py = 'x = issue7(1)  # the sweep (see ' + 'stop\n# 15)\ndef f():\n    """Graph colouring, issue\n    7."""\n'
    assert [m.group() for m in MILESTONE.finditer(python_prose(py))] == ["stop\n  15", "issue\n    7"]
    cpp = ('int issue7 = 0;  // block ' + 'stop 3\n/* a\n * issue\n * #12 */ const char* s = "stop 4";\n'
           'const char* r = R"x(issue 5)x"; char c = \'"\'; // stops here, 2 steps on\n')
    prose = cpp_prose(cpp)
    assert len(prose) == len(cpp) and prose.count("\n") == cpp.count("\n")
    assert [m.group() for m in MILESTONE.finditer(prose)] == ["stop 3", "issue\n * #12", "stop 4", "issue 5"]
    for fine in ("a released pin stops where it was put", "stop at frame 3", "reissue 2", "stop-15 build", "issues"):
        assert not MILESTONE.search(fine), fine


def test_the_identifier_pattern_finds_names_built_from_milestones():
    for bad in ("issue7(parts)", "PARTS_ISSUE7", "test_issue7_bench", "issue_7", "kStop15", "stop12 = 1"):
        assert IDENTIFIER.search(bad), bad
    for fine in ("reissue2", "nonstop3", "stop_time", "stops", "COST_PARTS", "Stopwatch1", "x = stop - 15"):
        assert not IDENTIFIER.search(fine), fine


def test_the_scanned_sets_are_not_empty():
    assert len(DOCS) >= 5 and len(PYTHON) >= 20 and len(CPP) >= 20 and len(WHOLE) >= 10


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_documents_name_no_milestone_and_link_nothing_outside(path: Path):
    text = path.read_text(encoding="utf-8")
    found = offences(MILESTONE, text, text, path) + offences(LINK, text, text, path)
    assert not found, "development milestones or outside links:\n" + "\n".join(found)


@pytest.mark.parametrize("path", PYTHON + CPP + WHOLE, ids=lambda p: str(p.relative_to(ROOT)))
def test_source_comments_name_no_milestone(path: Path):
    text = path.read_text(encoding="utf-8")
    if path in PYTHON:
        prose = python_prose(text)
    elif path in CPP:
        prose = cpp_prose(text)
    else:
        prose = text
    found = offences(MILESTONE, prose, text, path)
    assert not found, "development milestones in comments or strings:\n" + "\n".join(found)


@pytest.mark.parametrize("path", PYTHON + CPP + WHOLE, ids=lambda p: str(p.relative_to(ROOT)))
def test_source_names_are_not_built_from_milestones(path: Path):
    text = path.read_text(encoding="utf-8")
    found = offences(IDENTIFIER, text, text, path)
    assert not found, "names built from development milestones:\n" + "\n".join(found)
