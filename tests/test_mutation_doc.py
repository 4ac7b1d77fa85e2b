"""``docs/mutation.md`` is generated (``benchmarks/mutation_table.py``) from the committed mutation
results and the classification of their survivors: the page cannot drift from them, every
survivor has a class and a reason, and no classification outlives its mutant."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from conftest import ROOT


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"_{name}", ROOT / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_the_mutation_page_is_what_the_results_and_the_classification_give() -> None:
    table = _load("mutation_table")
    results, classified = table.load()
    page = table.render(results, classified)  # raises on an unclassified survivor or a stale classification
    assert Path(table.PAGE).read_text() == page, "docs/mutation.md is stale: python benchmarks/mutation_table.py --write"


def test_each_survivors_id_is_its_mutant_so_a_classification_follows_the_mutant() -> None:
    """The ids the classification is keyed by are recomputed from each survivor's module, operator
    and diff: an id edited by hand, or a diff that changed under it, does not pass."""
    table, bench = _load("mutation_table"), _load("bench_mutation")
    results, _ = table.load()
    for name, module in results["modules"].items():
        for s in module["survivors"]:
            assert s["id"] == bench.mutant_id(name, s["operator"], s["diff"]), (name, s["line"])
