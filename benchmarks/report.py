"""The benchmarks' committed results as the markdown tables the README and docs include.

    python benchmarks/report.py                         # the tables again from results/*.json
    python benchmarks/report.py --check                 # exit 1 if a table differs from its JSON
    python benchmarks/report.py --run density_edgedata  # run that benchmark, then the tables
    python benchmarks/report.py --list                  # the results, their files and commands

Every result is a JSON file in ``results/`` written by its benchmark (``-o``/``--results``). A
document includes its table between ``<!-- results:NAME -->`` and ``<!-- /results:NAME -->`` lines
(the corpus keeps ``<!-- corpus-table -->``, which its own script writes too); this script writes
each table from its file, so a figure in the docs is the committed file's. A results file unknown
here is drawn as its own ``table`` (markdown) or else a table of its ``rows`` (a list of objects),
and its top-level ``command`` (a string or an argument list, run from the repository root) is what
``--run NAME`` runs.

``emit`` is also here: the benchmark scripts' markdown report, printed and written with ``-o``.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def emit(text: str, output: str | None, title: str) -> None:
    """A benchmark's markdown report: printed, and written to ``output`` under a title."""
    print(text)
    if output:
        os.makedirs(os.path.dirname(os.path.abspath(output)), exist_ok=True)
        with open(output, "w") as f:
            f.write(f"# {title}\n\n{text}")


# ---- tables ------------------------------------------------------------------------------------
def _cell(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(map(_cell, value))
    return str(value).replace("|", "\\|").replace("\n", " ")


def generic_table(doc) -> str:
    """A results file's own markdown ``table`` where it writes one, else its ``rows`` (objects) as a
    table, their keys as columns in first-seen order."""
    if isinstance(doc, dict) and isinstance(doc.get("table"), str):
        return doc["table"].rstrip("\n") + "\n"
    rows = doc.get("rows") if isinstance(doc, dict) else doc
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise ValueError("no 'rows' list of objects to draw")
    keys = list(dict.fromkeys(k for r in rows for k in r))
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(_cell(r.get(k, "–")) for k in keys) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def density_edgedata_table(doc: dict) -> str:
    """``benchmarks/density_edgedata.py``: a fill's density against SUMO's edgeData."""
    asked = {r["asked"] for r in doc["rows"]}
    head = f"fill `--density {_cell(asked.pop())}`" if len(asked) == 1 else "fill (asked veh/km)"
    lines = [f"| {head} | car-lane km | vehicles seeded | edgeData veh/km | vs asked |",
             "|---|---|---|---|---|"]
    for r in doc["rows"]:
        err = f"{100 * r['error']:+.1f} %".replace("-", "−")
        lines.append(f"| `{r['network']}` | {r['car_lane_km']:.2f} | {r['seeded']} | {r['edgedata']:.1f} | {err} |")
    return "\n".join(lines) + "\n"


def corpus_table(doc: dict) -> str:
    """``benchmarks/scenarios.py``: the public scenario corpus, drawn by that script itself."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenarios
    return scenarios.markdown(scenarios._merge(RESULTS / "corpus.json", []))


@dataclass(frozen=True)
class Result:
    name: str
    table: Callable[[dict], str]
    command: list[str] | None = None    # how its benchmark writes results/NAME.json
    begin: str | None = None            # markers, when not <!-- results:NAME -->
    end: str | None = None

    @property
    def path(self) -> Path:
        return RESULTS / f"{self.name}.json"

    def markers(self) -> tuple[str, str]:
        return (self.begin or f"<!-- results:{self.name} -->", self.end or f"<!-- /results:{self.name} -->")

    def recorded(self):
        """The command as the results file records it (a string, an argument list) or None."""
        return json.loads(self.path.read_text()).get("command") if self.path.is_file() else None

    def run_command(self) -> list[str] | None:
        """The command to run (None: none recorded, or one given with words beside it that is not a
        command line: ``--list`` shows it, ``--run`` cannot run it)."""
        if self.command:
            return self.command
        cmd = self.recorded()
        try:
            return shlex.split(cmd) if isinstance(cmd, str) else cmd
        except ValueError:
            return None


KNOWN = {
    "density_edgedata": Result("density_edgedata", density_edgedata_table,
                               ["python", "benchmarks/density_edgedata.py", "-o", "results/density_edgedata.json"]),
    "corpus": Result("corpus", corpus_table,
                     ["python", "benchmarks/scenarios.py", "run", "--results", "results/corpus.json"],
                     "<!-- corpus-table -->", "<!-- /corpus-table -->"),
}


def results() -> dict[str, Result]:
    """Every committed results file, by name: the known ones and any other ``results/*.json``."""
    found = {p.stem: KNOWN.get(p.stem, Result(p.stem, generic_table)) for p in sorted(RESULTS.glob("*.json"))}
    return {**{n: r for n, r in KNOWN.items() if n not in found}, **found}


# ---- the documents -----------------------------------------------------------------------------
def fill_in(text: str, begin: str, end: str, table: str, where: str) -> str:
    """``text`` with every span between ``begin`` and ``end`` replaced by ``table``."""
    out, pos = [], 0
    while (i := text.find(begin, pos)) >= 0:
        j = text.find(end, i)
        if j < 0:
            raise ValueError(f"{where}: {begin} has no {end}")
        out += [text[pos:i + len(begin)], "\n", table]
        pos = j
    return "".join(out) + text[pos:]


def render(docs=DOCS, only: set[str] | None = None) -> dict[Path, str]:
    """Each document that includes a result, as it reads with its tables drawn from the JSON."""
    new = {}
    for res in results().values():
        if only and res.name not in only:
            continue
        begin, end = res.markers()
        for path in docs:
            text = new.get(path) or path.read_text()
            if begin not in text:
                continue
            if not res.path.is_file():
                raise FileNotFoundError(f"{path.relative_to(ROOT)} includes {res.name}, but "
                                        f"{res.path.relative_to(ROOT)} does not exist")
            new[path] = fill_in(text, begin, end, res.table(json.loads(res.path.read_text())),
                                str(path.relative_to(ROOT)))
    return new


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", nargs="+", default=[], metavar="NAME", help="run these benchmarks first")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if a table is out of date")
    ap.add_argument("--list", action="store_true", help="the results known, their files and commands")
    o = ap.parse_args(argv)
    known = results()
    if o.list:
        for r in known.values():
            cmd = r.run_command()
            text = shlex.join(cmd) if cmd else r.recorded() if isinstance(r.recorded(), str) else None
            print(f"{r.name}: {r.path.relative_to(ROOT)} ({'present' if r.path.is_file() else 'missing'}); "
                  f"{text or 'no command recorded'}")
        return 0
    for name in o.run:
        cmd = known[name].run_command() if name in known else None
        if not cmd:
            print(f"report.py: --run {name}: no benchmark command known for it", file=sys.stderr)
            return 2
        cmd = [sys.executable if cmd[0] == "python" else cmd[0], *cmd[1:]]
        if subprocess.run(cmd, cwd=ROOT).returncode:
            print(f"report.py: --run {name}: {shlex.join(cmd)} failed", file=sys.stderr)
            return 2
    try:
        new = render()
    except (OSError, ValueError, KeyError) as e:
        print(f"report.py: {e}", file=sys.stderr)
        return 2
    stale = [p for p, text in new.items() if p.read_text() != text]
    for p in stale:
        print(f"{'out of date' if o.check else 'wrote'}: {p.relative_to(ROOT)}")
        if not o.check:
            p.write_text(new[p])
    return 1 if o.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
