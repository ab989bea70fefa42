"""The mutation testing's configuration and its list of equivalent mutants are well formed (docs/mutation.md):
every module it mutates exists, every test it runs exists, and every equivalent mutant names one of those
modules, the change it makes and why that change is invisible."""

from __future__ import annotations

import tomllib

import yaml

from conftest import ROOT


def test_the_mutated_modules_and_their_tests_exist_and_every_equivalent_says_why():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mutmut"]
    modules = config["only_mutate"]
    assert modules and all((ROOT / m).is_file() for m in modules), modules
    assert all((ROOT / t).is_file() for t in config["pytest_add_cli_args_test_selection"])
    dotted = tuple(m.removesuffix(".py").replace("/", ".") + "." for m in modules)
    entries = yaml.safe_load((ROOT / "tests" / "mutation_equivalents.yaml").read_text())["equivalent"]
    assert entries and len({e["mutant"] for e in entries}) == len(entries)
    for entry in entries:
        assert entry["mutant"].startswith(dotted) and "__mutmut_" in entry["mutant"], entry
        assert entry["change"].strip() and len(entry["why"]) > 20, entry
