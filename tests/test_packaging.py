"""The package's dependencies: version ranges in pyproject.toml (``pip install .`` lives beside
other packages), exact pins in constraints.txt (``./sappcw`` installs with them, so a checkout
reproduces every number), each pin inside its range, and this environment holding exactly the
pins.  The package data (scenarios, parameter files, the Foxglove layout) is declared for the
wheel; tests/test_install.py installs the wheel and runs it."""

from __future__ import annotations

import importlib.metadata as md
import re
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

from conftest import ROOT

tomllib = pytest.importorskip("tomllib")  # Python 3.11+

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
CONSTRAINTS = ROOT / "constraints.txt"


def _pins() -> dict[str, Version]:
    pins: dict[str, Version] = {}
    for n, line in enumerate(CONSTRAINTS.read_text().splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        m = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;#]+)", line)
        assert m, f"constraints.txt:{n}: {line!r} is not NAME==VERSION"
        name = canonicalize_name(m.group(1))
        assert name not in pins, f"constraints.txt:{n}: {name} pinned twice"
        pins[name] = Version(m.group(2))
    return pins


def _requirements() -> list[tuple[str, Requirement]]:
    """(where, requirement) of the dependencies, every extra's and the build system's."""
    project = PYPROJECT["project"]
    out = [("dependencies", Requirement(r)) for r in project["dependencies"]]
    out += [(f"optional-dependencies.{extra}", Requirement(r)) for extra, reqs in project["optional-dependencies"].items() for r in reqs]
    out += [("build-system.requires", Requirement(r)) for r in PYPROJECT["build-system"]["requires"]]
    return out


def test_pyproject_states_ranges_not_pins() -> None:
    for where, req in _requirements():
        ops = {s.operator for s in req.specifier}
        assert ops, f"{where}: {req} has no version range"
        assert not ops & {"==", "==="}, f"{where}: {req} is an exact pin; pins belong in constraints.txt"


def test_every_requirement_is_pinned_inside_its_range() -> None:
    pins = _pins()
    for where, req in _requirements():
        name = canonicalize_name(req.name)
        assert name in pins, f"{where}: {req.name} has no pin in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), f"{where}: the pin {name}=={pins[name]} is outside {req}"


def test_this_environment_holds_exactly_the_pins() -> None:
    """What ./sappcw installed (the test, basilisk and docs extras): every pinned distribution
    that is installed has its pinned version, and every requirement of the package and of those
    extras is installed."""
    pins = _pins()
    installed = {canonicalize_name(d.metadata["Name"]): Version(d.version) for d in md.distributions()}
    wrong = {n: f"{installed[n]} (pinned {v})" for n, v in pins.items() if n in installed and installed[n] != v}
    assert not wrong, f"installed versions differ from constraints.txt: {wrong} (./sappcw rebuilds .venv when the file changes)"
    project = PYPROJECT["project"]
    wanted = [*project["dependencies"], *(r for extra in ("test", "basilisk", "docs") for r in project["optional-dependencies"][extra])]
    missing = [r for r in wanted if canonicalize_name(Requirement(r).name) not in installed]
    assert not missing, missing


def test_the_package_data_is_declared_for_the_wheel() -> None:
    """Every file of src/sappc/data matches a package-data pattern (a new kind of file would be
    left out of the wheel silently), and the checkout's config/ is that folder."""
    patterns = PYPROJECT["tool"]["setuptools"]["package-data"]["sappc"]
    data = ROOT / "src" / "sappc" / "data"
    files = [p.relative_to(data.parent) for p in data.rglob("*") if p.is_file() and "__pycache__" not in p.parts]
    assert files and all(any(f.match(pattern) and len(f.parts) == len(Path(pattern).parts) for pattern in patterns) for f in files), files
    assert (ROOT / "config").is_symlink() and (ROOT / "config").resolve() == data.resolve()
