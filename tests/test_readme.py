"""The README's examples run, and its commands name flags their programs know.

* Every code block preceded by a ``<!-- runnable -->`` line is run from the repository root
  (``bash`` blocks with ``bash -e``, ``python`` blocks with ``python -c``), in README order; each
  ``-o/--out/--output-dir DIR`` is redirected under the test's temporary directory, so nothing is
  written into the tree. Unmarked blocks (the install line, hour-long runs) are never run.
* Every ``python -m sumo_scendiff.X [stage] ...`` command in the README (code blocks and inline
  code) is checked against X's own parser: each flag it uses must appear in
  ``python -m sumo_scendiff.X [stage] --help``. Flags being added (``PENDING``) only warn while the
  parser lacks them.
"""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import warnings
from functools import lru_cache
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
MARK = "<!-- runnable -->"

# flags the README documents that are being added to a parser right now: warn, do not fail, while
# the parser lacks them (remove an entry once its parser has it)
# (-c, -a and --ego-after of `run` were pending while this test was written; all are in now)
PENDING: dict[str, set[str]] = {"run": set(), "sweep": set()}
# SUMO's own options the README names in inline code (not flags of this package)
SUMO_OPTIONS = {"--lateral-resolution", "--collision.mingap-factor", "--load-state"}
OUT_FLAG = re.compile(r"(?<!\S)(-o|--out|--output-dir)(\s+|=)(\S+)")


def blocks() -> list[tuple[int, str, str, bool]]:
    """(line, language, text, runnable) of every fenced code block of the README."""
    out, lines, i = [], README.read_text().split("\n"), 0
    while i < len(lines):
        m = re.match(r"^```(\w*)\s*$", lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while not lines[j].startswith("```"):
            j += 1
        runnable = i > 0 and lines[i - 1].strip() == MARK
        out.append((i + 1, m.group(1), "\n".join(lines[i + 1:j]), runnable))
        i = j + 1
    return out


def runnable_blocks():
    return [b for b in blocks() if b[3]]


def test_runnable_blocks_are_marked_and_safe():
    text = README.read_text()
    marks = text.count(MARK)
    assert marks == len(runnable_blocks()) and marks >= 3, "a runnable mark not right before a fence"
    for line, lang, code, _ in runnable_blocks():
        assert lang in ("bash", "python"), f"README line {line}: runnable {lang!r} block"
        assert "pip install" not in code, f"README line {line}: installs must not be marked runnable"
        if lang == "bash":
            for cmd in commands(code):
                if "sumo_scendiff.run" in cmd or "sumo_scendiff.sweep" in cmd:
                    assert OUT_FLAG.search(cmd), f"README line {line}: a runnable command writes " \
                        f"into the tree (give it -o): {cmd}"
    first = blocks()[0][2]
    assert "python -m pytest -q" in first and "pip install" in first
    test_command = next(c for c in commands(first) if "pytest" in c).split("&&")[-1].strip()
    assert test_command in (ROOT / ".ci" / "run").read_text().splitlines(), ".ci/run runs another test command"


def _env():
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", "1")
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("readme")


@pytest.mark.parametrize("line,lang,code", [(b[0], b[1], b[2]) for b in runnable_blocks()],
                         ids=[f"line{b[0]}-{b[1]}" for b in runnable_blocks()])
def test_runnable_block(line, lang, code, out_dir):
    if lang == "bash":
        code = OUT_FLAG.sub(lambda m: f"{m.group(1)}{m.group(2)}{shlex.quote(str(out_dir / m.group(3)))}", code)
        argv = ["bash", "-e", "-o", "pipefail", "-c", code]
    else:
        argv = [sys.executable, "-c", code]
    p = subprocess.run(argv, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, f"README line {line} failed ({p.returncode}):\n{code}\n--- stdout\n" \
        f"{p.stdout[-3000:]}\n--- stderr\n{p.stderr[-3000:]}"
    if "sumo_scendiff.run" in code and "no-such" not in code:
        for m in OUT_FLAG.finditer(code):
            out = Path(m.group(3))
            assert (out / "run.json").is_file(), f"README line {line}: no run.json in {out}"
            assert (out / "scene_000" / "scenario.sumocfg").is_file()
    if "no-such" in code:
        assert "exit code 2" in p.stdout and "Traceback" not in p.stderr


# ---- flags -----------------------------------------------------------------------------------
def commands(code: str) -> list[str]:
    """The shell commands of a block: continuation lines joined, comments dropped."""
    code = re.sub(r"\\\n\s*", " ", code)
    return [ln.split(" #")[0].strip() for ln in code.split("\n") if ln.strip() and not ln.lstrip().startswith("#")]


def readme_commands() -> list[str]:
    """Every `python -m sumo_scendiff.X ...` of the README: in code blocks and in inline code."""
    found = []
    for _, lang, code, _ in blocks():
        if lang in ("bash", ""):
            for cmd in commands(code):
                for part in re.split(r"&&|\|\||;", cmd):
                    if "python -m sumo_scendiff." in part:
                        found.append(part.strip())
    prose = re.sub(r"```.*?```", "", README.read_text(), flags=re.S)
    found += [s for s in re.findall(r"`([^`]+)`", prose) if s.startswith("python -m sumo_scendiff.")]
    return found


@lru_cache(maxsize=None)
def help_text(module: str, stage: str | None) -> str:
    argv = [sys.executable, "-m", f"sumo_scendiff.{module}"] + ([stage] if stage else []) + ["--help"]
    p = subprocess.run(argv, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, f"{' '.join(argv[1:])}: {p.stderr[-2000:]}"
    return p.stdout


def knows(help_: str, flag: str) -> bool:
    return re.search(r"(?<![\w-])" + re.escape(flag) + r"(?![\w-])", help_) is not None


def split_command(cmd: str) -> tuple[str, str | None, list[str]]:
    words = cmd.split()
    module = words[2][len("sumo_scendiff."):]
    rest = words[3:]
    stage = rest[0] if module == "train" and rest and not rest[0].startswith("-") else None
    if stage and "|" in stage:         # `train autoencoder|diffusion|export`
        stage = stage.split("|")[0]
    flags = [w.split("=")[0] for w in rest if re.match(r"^--?[A-Za-z][\w.-]*(=.*)?$", w)]
    return module, stage, flags


def test_readme_commands_use_flags_their_parsers_know():
    unknown, pending = [], []
    for cmd in readme_commands():
        module, stage, flags = split_command(cmd)
        h = help_text(module, stage)
        for flag in flags:
            if knows(h, flag):
                continue
            (pending if flag in PENDING.get(module, ()) else unknown).append(f"{module}: {flag} ({cmd})")
    for p in sorted(set(pending)):
        warnings.warn(f"README flag not in the parser yet: {p}")
    assert not unknown, "README commands use flags their parsers do not know:\n" + "\n".join(sorted(set(unknown)))


def test_readme_inline_flags_exist():
    """Every flag the README names in inline code (the knob table) is one of `run`'s, `fill`'s or
    `sweep`'s (or SUMO's own options)."""
    prose = re.sub(r"```.*?```", "", README.read_text(), flags=re.S)
    spans = re.findall(r"`([^`]+)`", prose)
    flags = set()
    for s in spans:
        if s.startswith("python "):
            continue
        for w in re.findall(r"(?<![\w-])(--?[A-Za-z][\w.-]*)", s):
            if w.startswith("--") or re.fullmatch(r"-[a-zA-Z]", w):
                flags.add(w)
    known = help_text("run", None) + help_text("sweep", None) + help_text("fill", None)
    pending = set().union(*PENDING.values())
    missing = sorted(f for f in flags if f not in SUMO_OPTIONS and f not in pending and not knows(known, f))
    assert not missing, f"README names flags no parser knows: {missing}"


# ---- a guide, not a notebook -------------------------------------------------------------------
def test_readme_is_a_guide():
    """Short enough to read in one sitting; its figures point at committed files or commands, not
    at one machine's `runs/`; no dates, rounds or commit prefixes in its tables; links resolve."""
    text = README.read_text()
    assert len(text.splitlines()) <= 250, f"README.md has {len(text.splitlines())} lines (at most 250)"
    assert "runs/" not in text, "README.md names a runs/ path (not in git)"
    for line in text.split("\n"):
        if line.startswith("|"):
            for bad in (r"\b20\d\d-\d\d-\d\d\b", r"\bround \d+", r"\b[0-9a-f]{7,8}…"):
                assert not re.search(bad, line), f"README table cell with {bad!r}: {line[:120]}"
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if "://" not in target:
            assert (ROOT / target).exists(), f"README links to a missing file: {target}"
    assert "repository root" in text      # where the commands run from
