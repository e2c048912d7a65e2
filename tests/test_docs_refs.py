"""The docs name only files that exist, and docs/benchmarks/ holds only results something cites.

Pure file checks (no physhand_mj import). Checked in README.md, benchmarks/README.md and docs/*.md:
relative link targets; `docs/benchmarks/...` and `docs/images/...` paths (in docs pages also the
page-relative `benchmarks/NAME.json` and `images/NAME.png`); `benchmarks/*.py` and `benchmarks/*.sh`
scripts, except where the text right after says "removed; in git history at COMMIT". A path may be a
pattern (`*`, `{a,b}`, `<name>`): then some file must match it.
"""

import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.fast

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", ROOT / "benchmarks" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
REMOVED = "removed; in git history at"
RESULT = r"[\w\-.*{},<>]+\.(?:json|csv|log|txt|png|gif|mp4|svg)"


def _regex(pattern: str) -> re.Pattern:
    """`*` any run, `<name>` one underscore-free token, `{a,b}` alternatives; the rest literal."""
    out = ""
    for tok in re.split(r"(\*|<[^>]*>|\{[^{}]*\})", pattern):
        if tok == "*":
            out += ".*"
        elif tok.startswith("<"):
            out += "[^_/]+"
        elif tok.startswith("{"):
            out += "(?:" + "|".join(re.escape(a) for a in tok[1:-1].split(",")) + ")"
        else:
            out += re.escape(tok)
    return re.compile(out)


def _exists(path: Path) -> bool:
    if not re.search(r"[*{<]", str(path)):
        return path.exists()
    rx = _regex(path.name)
    return path.parent.is_dir() and any(rx.fullmatch(p.name) for p in path.parent.iterdir())


def _named_paths(page: Path):
    """(path, line) for every file path the page names, resolved from the project root."""
    text = page.read_text()
    line = lambda i: text.count("\n", 0, i) + 1  # noqa: E731
    for m in re.finditer(r"\]\(([^)\s#]+)(?:#[^)]*)?\)", text):  # relative link targets
        if not re.match(r"[a-z]+:", m.group(1)):
            yield (page.parent / m.group(1)).resolve(), line(m.start())
    for m in re.finditer(r"(?<![\w/.])((?:docs/)?(?:benchmarks|images)/" + RESULT + ")", text):
        p = m.group(1)
        if not p.startswith("docs/") and page.parent.name != "docs":
            continue  # README's bare benchmarks/... result names: not paths
        yield (ROOT / p if p.startswith("docs/") else page.parent / p), line(m.start())
    for m in re.finditer(r"(?<![\w/.])benchmarks/[\w/]+\.(?:py|sh)\b", text):
        if REMOVED not in text[m.end():m.end() + 300]:
            yield ROOT / m.group(0), line(m.start())


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_paths_the_docs_name_exist(page):
    missing = sorted({f"{page.name}:{n}: {p.relative_to(ROOT) if p.is_relative_to(ROOT) else p}"
                      for p, n in _named_paths(page) if not _exists(p)})
    assert not missing, "named but missing (fix the name, or say `removed; in git history at COMMIT`):\n" + \
        "\n".join(missing)


def test_every_result_file_is_cited():
    """Each file under docs/benchmarks/ is named (or matched by a pattern) in a docs page, a README, a
    test, a benchmark script or the library; `_cuda.json` right after `x_cpu.json` names `x_cuda.json`."""
    sources = [*PAGES, ROOT / "CHANGELOG.md", *(ROOT / "docs").glob("*.md")]
    for d in ("benchmarks", "tests", "physhand_mj", "plugins", "examples"):
        sources += [p for p in (ROOT / d).rglob("*") if p.suffix in (".py", ".md", ".sh")]
    names = sorted(p.name for p in (ROOT / "docs" / "benchmarks").iterdir())
    cited = set()
    for src in sources:
        if not src.is_file():
            continue
        text = src.read_text(errors="ignore")
        cited.update(n for n in names if n in text)
        for m in re.finditer(RESULT, text):
            pat = m.group(0).split("/")[-1].replace("<device>", "{cpu,cuda}")
            pats = [pat]
            if pat.startswith("_"):  # a suffix: the name before it in the text, cut at an underscore
                before = re.findall(r"(?<!\w)([A-Za-z][\w\-]*)\.(?:json|csv|log|txt)", text[max(0, m.start() - 300):m.start()])
                parts = before[-1].split("_") if before else []
                pats = ["_".join(parts[:k]) + pat for k in range(2, len(parts))]
            for pat in pats:
                if re.fullmatch(r"\*+\.\w+", pat):  # `*.json`: every file, not a citation
                    continue
                rx = _regex(pat)
                cited.update(n for n in names if rx.fullmatch(n))
    orphans = [n for n in names if n not in cited]
    assert not orphans, f"{len(orphans)} files under docs/benchmarks/ that nothing cites (delete them, or cite " \
        "them where their figures are reported):\n" + "\n".join(orphans)
