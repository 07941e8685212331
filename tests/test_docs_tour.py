"""A tour of the docs: a clone of the repository is all a reader needs.

* Every relative markdown link in README.md and docs/**/*.md resolves to a file inside the repository
  (and its ``#anchor``, if any, to a heading of that file).
* Every backticked repository path in those files (`analysis/pod.py`, `docs/sweep.md`, `configs/rigs/`,
  `daq/report.py:build_report`, a bare `seed.md` beside the doc) exists, unless git ignores it (a bench
  output such as `bench/results/x.json`) or it is a placeholder (`drivers/<transport>/driver.py`).
* No tracked file names a path outside the repository (the team's old shared folder or a machine's /work).
* Every citation of a project note by section, anywhere in a tracked file — "method-detection §1.6",
  "method-nsi D3", "method-nsi.md §1.7–1.10", "landscape.md §1a, §2.2–2.3", "dependency-notes §3",
  "[method-nsi.md](method-nsi.md) §D3" — names a numbered heading of docs/<note>.md; a note named by file
  ("detection-findings.md") exists.

``PENDING`` lists docs that are cited but not written yet (none now): references to them are set apart
instead of failing the tour, so a doc can be cited in the commit before the one that writes it.

The checkers take the repository root and file lists as arguments, so ``test_checkers_catch_planted_errors``
can show each one failing on a small planted tree.
"""

from __future__ import annotations

import re
import subprocess
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PENDING: set[str] = set()  # none now: docs/architecture.md, the last one, exists
NOTES = ("method-detection", "method-nsi", "method-wbemd-slowflow", "landscape", "dependency-notes",
         "detection-findings", "architecture")
OUTSIDE = ("../" + "shared", "/" + "work/")  # split so that this file does not name them itself
SELF = Path(__file__).resolve().relative_to(ROOT).as_posix()

_FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
_CODE_SPAN = re.compile(r"`[^`\n]+`")
_INLINE_LINK = re.compile(r"!?\[[^\]\n]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REF_LINK = re.compile(r"^\s{0,3}\[[^\]\n]+\]:\s+<?(\S+?)>?(?:\s+\"[^\"]*\")?\s*$", re.M)
_SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")
_HEADING = re.compile(r"^#{1,6}[ \t]+(.+?)[ \t#]*$", re.M)
_HEADING_ID = re.compile(r"^§?\s?((?:\d+[a-z]?)(?:\.\d+)*|D\d+)(?=[.\s:)]|$)")

_NUM = r"(?:\d+[a-z]?(?:\.\d+)*|D\d+)"
_REF = rf"§?\s?{_NUM}(?:\s?[–-]\s?§?{_NUM})?"
_SEP = r"(?:\s*(?:,|/|;|and|&)?\s*(?:\#\s*)?)"
# a note's name, its ".md", an optional link tail "](...)" or ")", then section refs; a bare D-ref needs no §
_CITE = re.compile(
    rf"\b(?:docs/)?({'|'.join(NOTES)})(\.md)?(?:\]\([^)\s]*\)|\))?"
    rf"((?:{_SEP}(?:§\s?{_NUM}(?:\s?[–-]\s?§?{_NUM})?|D\d+(?:\s?[–-]\s?D?\d+)?)(?![\w.]*\w))*)"
)
# the reverse order: "§2.6 of docs/method-nsi.md"
_CITE_BEFORE = re.compile(rf"§\s?({_NUM})\s+of\s+(?:the\s+)?(?:`|\[)?(?:\.\./)*(?:docs/)?({'|'.join(NOTES)})\b")
_REF_ONE = re.compile(rf"§?\s?({_NUM})(?:\s?[–-]\s?§?({_NUM}))?")


# --- inputs -----------------------------------------------------------------------------------------------

def git(root: Path, *args: str, stdin: str | None = None) -> str:
    return subprocess.run(["git", *args], cwd=root, input=stdin, capture_output=True, text=True, check=True).stdout


def tracked_files(root: Path) -> list[str]:
    try:
        return git(root, "ls-files", "-z").split("\0")[:-1]
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tour needs `git ls-files`")


def doc_files(root: Path) -> list[str]:
    """README.md and every docs/**/*.md on disk (tracked or not yet: a new doc is toured before it is added)."""
    docs = ["README.md"] if (root / "README.md").exists() else []
    return docs + sorted(p.relative_to(root).as_posix() for p in (root / "docs").rglob("*.md"))


def read_text(root: Path, rel: str) -> str | None:
    """The file as UTF-8 text, or None for a binary or unreadable file."""
    try:
        data = (root / rel).read_bytes()
    except OSError:
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def prose(text: str) -> str:
    """Markdown with fenced code blocks blanked (line numbers kept)."""
    return _FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), text)


def line_of(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


# --- headings -----------------------------------------------------------------------------------------------

def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    s = re.sub(r"`|\*\*|__|\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", s).replace(" ", "-")


def headings(text: str) -> list[str]:
    return [m.group(1) for m in _HEADING.finditer(prose(text))]


def anchors(text: str) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for h in headings(text):
        s = slug(h)
        n = seen.get(s, 0)
        out.add(s if n == 0 else f"{s}-{n}")
        seen[s] = n + 1
    return out


def section_ids(text: str) -> set[str]:
    """The numbers and errata ids that open headings: "## 1. Algorithms" -> "1", "### D3. ..." -> "D3"."""
    return {m.group(1) for h in headings(text) if (m := _HEADING_ID.match(h))}


# --- checkers -----------------------------------------------------------------------------------------------

def _inside(root: Path, path: Path) -> bool:
    try:
        path.resolve().relative_to(root.resolve())
    except ValueError:
        return False
    return True


def broken_links(root: Path, docs: Iterable[str]) -> tuple[list[str], list[str]]:
    """(problems, pending) for the relative markdown links of ``docs``."""
    bad: list[str] = []
    pending: list[str] = []
    for rel in docs:
        body = prose(read_text(root, rel) or "")
        body = _CODE_SPAN.sub(lambda m: " " * len(m.group(0)), body)
        targets = [(m.start(), m.group(1)) for m in _INLINE_LINK.finditer(body)]
        targets += [(m.start(), m.group(1)) for m in _REF_LINK.finditer(body)]
        for pos, target in targets:
            if _SCHEME.match(target):
                continue  # http(s), mailto: not this test's business
            where = f"{rel}:{line_of(body, pos)}: ({target})"
            path_part, _, fragment = target.partition("#")
            dest = (root / rel).parent / path_part if path_part else root / rel
            if not _inside(root, dest):
                bad.append(f"{where} leaves the repository")
                continue
            dest_rel = dest.resolve().relative_to(root.resolve()).as_posix()
            if not dest.exists():
                (pending if dest_rel in PENDING else bad).append(f"{where} -> {dest_rel} does not exist")
                continue
            if fragment and dest.suffix == ".md" and fragment not in anchors(read_text(root, dest_rel) or ""):
                bad.append(f"{where} -> no heading with anchor #{fragment} in {dest_rel}")
    return bad, pending


def _expand_braces(token: str) -> list[str]:
    m = re.search(r"\{([^{}]*)\}", token)
    if not m:
        return [token]
    return [x for alt in m.group(1).split(",") for x in _expand_braces(token[: m.start()] + alt + token[m.end():])]


def broken_paths(root: Path, docs: Iterable[str], tracked: Iterable[str],
                 ignored: set[str] | None = None) -> tuple[list[str], list[str]]:
    """(problems, pending) for backticked repository paths in ``docs``.

    A token counts as a path when it has no blanks and either starts with a tracked top-level folder
    (`analysis/...`, `docs/...`) or is a top-level tracked file (`Makefile`) or a bare `name.md` (resolved
    beside the doc). Suffixes naming a symbol or a line (`:build_report`, `::test_x`, `:12`) are dropped, braces
    expanded; tokens with placeholders (`<name>`, `NAME`) or globs are skipped; paths git ignores (outputs)
    are allowed to be absent.
    """
    tracked = list(tracked)
    tops = {p.split("/", 1)[0] for p in tracked if "/" in p}
    top_files = {p for p in tracked if "/" not in p}
    candidates: list[tuple[str, str]] = []
    for rel in docs:
        body = prose(read_text(root, rel) or "")
        for m in _CODE_SPAN.finditer(body):
            token = m.group(0)[1:-1].strip()
            if re.search(r"\s|[<>*?$]|\.\.\.|…", token):
                continue
            bare_md = re.fullmatch(r"[\w.-]+\.md", token) is not None
            if not (token in top_files or bare_md or ("/" in token and token.split("/", 1)[0] in tops)):
                continue
            token = re.sub(r"(?:::?[A-Za-z_][\w.]*|:\d+(?:[-–]\d+)?)+$", "", token)
            if re.search(r"/[A-Z][A-Z0-9_]*(?:[./]|$)", token):
                continue  # configs/rigs/NAME.toml: a placeholder
            base = (root / rel).parent if bare_md else root
            for path in _expand_braces(token):
                dest = base / path.rstrip("/")
                candidates.append((f"{rel}:{line_of(body, m.start())}: `{m.group(0)[1:-1]}`", str(dest)))
    missing = [(where, dest) for where, dest in candidates if not Path(dest).exists()]
    if ignored is None:
        rels = [Path(d).relative_to(root).as_posix() for _, d in missing if _inside(root, Path(d))]
        try:
            ignored = set(git(root, "check-ignore", "--no-index", "--stdin", stdin="\n".join(rels)).split())
        except subprocess.CalledProcessError:  # exit 1: nothing ignored
            ignored = set()
    bad: list[str] = []
    pending: list[str] = []
    for where, dest in missing:
        if not _inside(root, Path(dest)):
            bad.append(f"{where} leaves the repository")
            continue
        dest_rel = Path(dest).relative_to(root).as_posix()
        if dest_rel in ignored:
            continue
        (pending if dest_rel in PENDING else bad).append(f"{where} -> {dest_rel} does not exist")
    return bad, pending


def outside_paths(root: Path, files: Iterable[str]) -> list[str]:
    """Lines of ``files`` that name a path outside the repository."""
    bad = []
    for rel in files:
        text = read_text(root, rel)
        if text is None:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if any(s in line for s in OUTSIDE):
                bad.append(f"{rel}:{n}: {line.strip()[:160]}")
    return bad


def _cited_ids(refs: str) -> list[str]:
    """Section ids named by a run of refs: "§1.7–1.10, §1.16" -> 1.7 1.8 1.9 1.10 1.16; "D1–D3" -> D1 D2 D3."""
    out: list[str] = []
    for m in _REF_ONE.finditer(refs):
        lo, hi = m.group(1), m.group(2)
        if hi is None:
            out.append(lo)
            continue
        if lo.startswith("D") and not hi.startswith("D"):
            hi = "D" + hi
        p_lo, _, last_lo = lo.rpartition(".") if "." in lo else ("", "", lo)
        p_hi, _, last_hi = hi.rpartition(".") if "." in hi else ("", "", hi)
        prefix = "D" if lo.startswith("D") else ""
        a, b = last_lo.removeprefix(prefix), last_hi.removeprefix(prefix)
        if p_lo == p_hi and a.isdigit() and b.isdigit() and int(a) <= int(b):
            dot = "." if p_lo else ""
            out += [f"{p_lo}{dot}{prefix}{k}" for k in range(int(a), int(b) + 1)]
        else:
            out += [lo, hi]
    return out


def bad_citations(root: Path, files: Iterable[str]) -> tuple[list[str], list[str]]:
    """(problems, pending): citations of docs/<note>.md by section or by file name that do not resolve."""
    notes: dict[str, set[str] | None] = {}

    def ids_of(note: str) -> set[str] | None:
        if note not in notes:
            text = read_text(root, f"docs/{note}.md")
            notes[note] = None if text is None else section_ids(text)
        return notes[note]

    bad: list[str] = []
    pending: list[str] = []
    for rel in files:
        text = read_text(root, rel)
        if text is None:
            continue
        found = [(m.start(), m.group(1), bool(m.group(2)), m.group(3) or "") for m in _CITE.finditer(text)]
        found += [(m.start(), m.group(2), True, "§" + m.group(1)) for m in _CITE_BEFORE.finditer(text)]
        for pos, note, by_file, refs in found:
            cited = _cited_ids(refs)
            if not cited and not by_file:
                continue  # the word alone ("landscape"), not a citation
            where = f"{rel}:{line_of(text, pos)}: {note}{' ' + refs.strip() if cited else '.md'}"
            ids = ids_of(note)
            if ids is None:
                (pending if f"docs/{note}.md" in PENDING else bad).append(f"{where} -> docs/{note}.md does not exist")
                continue
            missing = [c for c in cited if c not in ids]
            if missing:
                bad.append(f"{where} -> no heading {', '.join(missing)} in docs/{note}.md")
    return bad, pending


# --- the tour -------------------------------------------------------------------------------------------------

def _report(problems: list[str]) -> str:
    return f"{len(problems)} problem(s):\n" + "\n".join(problems)


def test_relative_links_resolve_inside_the_repository():
    bad, _ = broken_links(ROOT, doc_files(ROOT))
    assert not bad, _report(bad)


def test_backticked_repository_paths_exist():
    bad, _ = broken_paths(ROOT, doc_files(ROOT), tracked_files(ROOT))
    assert not bad, _report(bad)


def test_no_file_names_a_path_outside_the_repository():
    files = sorted(set(tracked_files(ROOT)) | set(doc_files(ROOT)))
    bad = outside_paths(ROOT, files)
    assert not bad, _report(bad)


def _citing_files() -> list[str]:
    """Tracked files and docs on disk, without this file (its planted tree cites missing sections on purpose)."""
    return sorted((set(tracked_files(ROOT)) | set(doc_files(ROOT))) - {SELF})


def test_section_citations_name_existing_headings():
    files = _citing_files()
    bad, _ = bad_citations(ROOT, files)
    assert not bad, _report(bad)


def test_the_method_notes_cite_the_seed_in_full():
    for rel in ["README.md", "docs/seed.md", "docs/method-detection.md", "docs/method-nsi.md",
                "docs/method-wbemd-slowflow.md"]:
        text = " ".join(re.sub(r"(?m)^\s*>\s?", "", read_text(ROOT, rel) or "").split())  # blockquotes unwrapped
        for part in ("Keegan James Moore", "Data-Driven System Identification of Strongly Nonlinear Modal Interactions",
                     "University of Illinois at Urbana-Champaign", "2019", "IDEALS"):
            assert part in text, f"{rel} does not cite the seed in full: {part!r} missing"


# --- the checkers can fail ------------------------------------------------------------------------------------

def test_checkers_catch_planted_errors(tmp_path: Path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "analysis").mkdir()
    (tmp_path / "analysis" / "pod.py").write_text(
        '"""POMs (method-detection §1.6, §9.9; method-nsi D3, D42; dependency-notes §3)."""\n'
        "# §2.6 of docs/method-nsi.md, method-nsi.md §1.7–1.9, see " + OUTSIDE[0] + "/docs/x.md\n"
    )
    (tmp_path / "docs" / "method-detection.md").write_text("# Note\n## 1. A\n### 1.6 Windows\n")
    (tmp_path / "docs" / "method-nsi.md").write_text("# Note\n### 1.7 x\n### 1.9 z\n## 4. Errata\n### D3. h\n")
    (tmp_path / "docs" / "guide.md").write_text(
        "See [windows](method-detection.md#16-windows), [gone](missing.md), [up](../../etc/passwd),\n"
        "[bad anchor](method-detection.md#17-smoothing), [later](architecture.md), [web](https://example.org).\n"
        "Code in `analysis/pod.py`, `analysis/{pod,nope}.py:fn`, `analysis/gone.py`, `configs/rigs/NAME.toml`.\n"
        "```\n[in code](nowhere.md)\n```\n"
    )
    (tmp_path / "README.md").write_text("Read [the guide](docs/guide.md) and `docs/guide.md`.\n")
    docs = doc_files(tmp_path)
    tracked = ["README.md", "analysis/pod.py", "docs/guide.md", "docs/method-detection.md", "docs/method-nsi.md"]

    bad, pending = broken_links(tmp_path, docs)
    assert sorted(b.split(": (")[1].split(")")[0] for b in bad) == sorted(
        ["missing.md", "../../etc/passwd", "method-detection.md#17-smoothing", "architecture.md"])
    assert pending == []

    bad, _ = broken_paths(tmp_path, docs, tracked, ignored=set())
    assert sorted(b.rsplit("-> ", 1)[1] for b in bad) == ["analysis/gone.py does not exist", "analysis/nope.py does not exist"]

    assert [b.split(":")[0:2] for b in outside_paths(tmp_path, tracked)] == [["analysis/pod.py", "2"]]

    bad, _ = bad_citations(tmp_path, tracked)
    assert sorted(b.rsplit("-> ", 1)[1] for b in bad) == sorted([
        "no heading 9.9 in docs/method-detection.md",
        "no heading D42 in docs/method-nsi.md",
        "docs/dependency-notes.md does not exist",
        "docs/architecture.md does not exist",
        "no heading 2.6 in docs/method-nsi.md",
        "no heading 1.8 in docs/method-nsi.md",
    ])


def test_citation_ranges_expand():
    assert _cited_ids("§1.7–1.10, §1.16") == ["1.7", "1.8", "1.9", "1.10", "1.16"]
    assert _cited_ids("§1a, §2.2–2.3") == ["1a", "2.2", "2.3"]
    assert _cited_ids("D1–D3") == ["D1", "D2", "D3"]
    assert _cited_ids("§1.9/§5.9") == ["1.9", "5.9"]
    assert section_ids("## 1. A\n### 1a. B\n### 2.10 C\n### D12. D\n## Tags\n") == {"1", "1a", "2.10", "D12"}
