"""The README and the docs stand alone: every relative link and every backticked repository path
they name exists in the repository, and none points outside it or at an issue tracker it lacks."""

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "src" / "nerf_transporter"
DOCS = sorted([REPO / "README.md", REPO / "results" / "README.md", *(REPO / "docs").rglob("*.md")])
# markdown links and images: [text](target) and ![text](target)
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
# inline code spans (single backticks), outside fenced code blocks
CODE = re.compile(r"`([^`\n]+)`")
# a backticked word names a repository path where it starts with one of these (from the root) ...
ROOT_PREFIXES = ("docs/", "results/", "configs/", "src/", "tests/", "benchmarks/", "notebooks/")
ROOT_FILES = ("README.md", "pyproject.toml", ".ci/run")
# ... or names a module or data file of the package by its path inside it (`sim/fingerprint.py`)
PACKAGE_FILE = re.compile(r"^[a-z_]+/[\w/.-]+\.(py|json)$")
# placeholders and patterns (`results/<task>/`, `configs/gpu/*.yaml`, `.../form2fit.json`)
NOT_A_PATH = re.compile(r"[<>*{}\[\]|$]|\.\.\.")
# "issue 34", "issues 11", "#34": a tracker the repository does not hold
ISSUE = re.compile(r"\b[Ii]ssues? #?\d+|(?<![\w&/#])#\d+\b")


def _prose(path: Path) -> str:
    """The document without its fenced code blocks (examples, not references)."""
    return re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)


def _named_paths(text: str) -> set[str]:
    """The repository paths the document's inline code names (words of a command too)."""
    paths = set()
    for span in CODE.findall(text):
        for word in span.split():
            word = word.rstrip(",;:").split("::")[0]  # a test's node id names its file
            if NOT_A_PATH.search(word):
                continue
            if word.startswith(ROOT_PREFIXES) or word in ROOT_FILES or PACKAGE_FILE.match(word):
                paths.add(word)
    return paths


def _exists(word: str) -> bool:
    """A named path exists from the repository root or, for a package file, inside the package."""
    if (REPO / word).exists():
        return True
    return not word.startswith(ROOT_PREFIXES) and (PACKAGE / word).exists()


@pytest.mark.parametrize("doc", DOCS, ids=lambda doc: str(doc.relative_to(REPO)))
def test_every_link_and_named_path_of_a_doc_exists_in_the_repository(doc):
    text = _prose(doc)
    dangling = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z]+:", target) or target.startswith("#"):
            continue  # a URL, or an anchor in the same page
        resolved = (doc.parent / target.split("#")[0]).resolve()
        if not resolved.is_relative_to(REPO) or not resolved.exists():
            dangling.append(f"link ({target})")
    dangling += [f"`{word}`" for word in sorted(_named_paths(text)) if not _exists(word)]
    assert not dangling, f"{doc.relative_to(REPO)} names what the repository lacks: {dangling}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda doc: str(doc.relative_to(REPO)))
def test_a_doc_points_at_nothing_outside_the_repository(doc):
    text = doc.read_text()
    outside = [m for m in ("shared/", "DESIGN.md") if m in text]
    outside += ISSUE.findall(text)
    assert not outside, f"{doc.relative_to(REPO)} points outside the repository: {outside}"
