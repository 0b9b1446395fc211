"""README.md and docs/ are references: what is true now, their figures from committed files.

* no work log: no "round N", no numbered work-log headings, no `runs/` paths (one machine's folders);
* every ``results/...`` file they name is in git, and every relative link resolves;
* the tables ``benchmarks/report.py`` draws from ``results/*.json`` are as the JSON says.
The weights card (sumo_scendiff/weights/README.md) is held to the same; CHANGELOG.md may name rounds: it is history.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "sumo_scendiff" / "weights" / "README.md"]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))
import report  # noqa: E402
import test_readme  # noqa: E402  (its command parsing, one definition)

WORK_LOG_HEADING = re.compile(r"^#{1,6}\s+(\d+[.)]\s|(session|round|item|step)\s+\d+)", re.I)


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _prose(path: Path) -> list[tuple[int, str]]:
    return list(enumerate(path.read_text().split("\n"), 1))


@pytest.mark.parametrize("path", DOCS, ids=_name)
def test_no_work_log(path):
    bad = []
    for n, line in _prose(path):
        if re.search(r"\bround \d+", line, re.I):
            bad.append(f"{_name(path)}:{n}: names a round: {line.strip()[:100]}")
        if "runs/" in line:
            bad.append(f"{_name(path)}:{n}: names a runs/ path (not in git): {line.strip()[:100]}")
        if WORK_LOG_HEADING.match(line):
            bad.append(f"{_name(path)}:{n}: a numbered work-log heading: {line.strip()}")
    assert not bad, "\n".join(bad)


def _tracked() -> set[str]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return set(out.split("\n"))


def test_results_files_they_name_are_committed():
    tracked, missing = _tracked(), []
    for path in DOCS:
        for n, line in _prose(path):
            for ref in re.findall(r"(?<![\w/.])(results/[\w.-]+\.(?:json|md|csv))", line):
                if ref not in tracked:
                    missing.append(f"{_name(path)}:{n}: {ref} is not in git")
    assert not missing, "\n".join(missing)


@pytest.mark.parametrize("path", DOCS, ids=_name)
def test_links_resolve(path):
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    broken = [t for t in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
              if "://" not in t and not t.startswith("mailto:") and not (path.parent / t).exists()]
    assert not broken, f"{_name(path)} links to missing files: {broken}"


def test_report_tables_match_the_committed_results():
    stale = [_name(p) for p, text in report.render().items() if p.read_text() != text]
    assert not stale, f"tables out of date with results/*.json (python benchmarks/report.py): {stale}"
    included = {r.name for r in report.results().values()
                if any(r.markers()[0] in p.read_text() for p in DOCS)}
    assert {"corpus", "density_edgedata"} <= included


def test_report_fills_between_markers_and_refuses_an_open_one():
    b, e = "<!-- results:x -->", "<!-- /results:x -->"
    text = f"a\n{b}\nold\n{e}\nb\n{b}\n{e}\n"
    assert report.fill_in(text, b, e, "| new |\n", "doc") == f"a\n{b}\n| new |\n{e}\nb\n{b}\n| new |\n{e}\n"
    with pytest.raises(ValueError, match="doc"):
        report.fill_in(f"{b}\nno end\n", b, e, "t", "doc")
    table = report.generic_table({"rows": [{"net": "a|b", "veh_km": 19.5}, {"net": "c"}]})
    assert table == "| net | veh_km |\n|---|---|\n| a\\|b | 19.5 |\n| c | – |\n"
    assert report.generic_table({"rows": [], "table": "| own |\n|---|"}) == "| own |\n|---|\n"


# the package's command-line programs (each has its own --help); other `python -m` lines name scripts
CLIS = {"run", "fill", "sweep", "evaluate", "train", "data", "export", "studio"}


def doc_commands(path: Path) -> list[str]:
    """Every `python -m sumo_scendiff.X ...` of a document, in code blocks and in inline code."""
    text, found = path.read_text(), []
    for code in re.findall(r"```\w*\n(.*?)```", text, re.S):
        for cmd in test_readme.commands(code):
            found += [part.strip()[part.strip().index("python -m"):] for part in re.split(r"&&|\|\||;", cmd)
                      if "python -m sumo_scendiff." in part]
    prose = re.sub(r"\s*\n\s*", " ", re.sub(r"```.*?```", "", text, flags=re.S))
    return found + [s for s in re.findall(r"`([^`]+)`", prose) if s.startswith("python -m sumo_scendiff.")]


@pytest.mark.slow   # each program's --help in a subprocess
@pytest.mark.parametrize("path", DOCS[1:], ids=_name)
def test_doc_commands_use_flags_their_programs_know(path):
    unknown = []
    for cmd in doc_commands(path):
        module, stage, flags = test_readme.split_command(cmd)
        if module.split(".")[0] not in CLIS or "." in module:
            continue
        h = test_readme.help_text(module, stage)
        unknown += [f"{module}: {f} ({cmd[:100]})" for f in flags if not test_readme.knows(h, f)]
    assert not unknown, f"{_name(path)}: flags no parser knows:\n" + "\n".join(sorted(set(unknown)))


def test_readme_corpus_row_is_the_committed_corpus():
    """The README's corpus figure is results/corpus.json's: scenarios with no failed step (a step
    skipped because the product exported nothing, and said why, is not a failure)."""
    rows = json.loads((ROOT / "results" / "corpus.json").read_text())["scenarios"]
    passed = sum(all(s.get("ok") is not False for s in r["steps"].values()) for r in rows)
    (row,) = [ln for ln in (ROOT / "README.md").read_text().split("\n") if "results/corpus.json" in ln]
    assert f"{passed} of {len(rows)}" in row, f"README's corpus row should read {passed} of {len(rows)}: {row}"
    corpus_md = re.sub(r"\s+", " ", (ROOT / "docs" / "corpus.md").read_text())
    assert f"Of {len(rows)} scenarios, {passed} pass" in corpus_md, "docs/corpus.md's count differs"
