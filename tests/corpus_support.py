"""The corpus harness (benchmarks/scenarios.py) loaded as a module, and the committed scenarios of
tests/data/corpus, for test_corpus.py (the harness) and test_corpus_scenarios.py (the scenarios)."""
from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
DATA = HERE / "data" / "corpus"
# a placement table's statuses (the product's, and the harness's "conflict")
STATUSES = {"placed", "misplaced", "refused", "existing", "dropped", "conflict"}


def load_corpus():
    spec = importlib.util.spec_from_file_location("corpus", HERE.parent / "benchmarks" / "scenarios.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod      # dataclasses look their module up while the class is made
    spec.loader.exec_module(mod)
    return mod


def entry(corpus, name):
    return next(s for s in corpus.REGISTRY if s.name == name)


def copy_scenario(name: str, tmp_path: Path, corpus) -> Path:
    """The committed scenario in a scratch folder: its configurations write outputs beside themselves."""
    shutil.copytree(DATA / name, tmp_path / name)
    return tmp_path / name / entry(corpus, name).config
