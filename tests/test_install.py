"""The package as ``pip install .`` installs it: a wheel built from the checkout, installed into a
new virtual environment and run from a directory outside the checkout, runs the paper's
experiment by name and prints the metrics docs/getting-started.md shows.

How, without the network and in the time of the suite: the wheel is built from a copy of the
sources with the ``setuptools`` of this environment (``--no-build-isolation``, no index), and
the new environment reaches this environment's installed packages through a ``.pth`` file that
``site.addsitedir``-s a directory of links to them, **leaving out this checkout's editable
install** (its ``.pth`` adds ``src/`` to the path).  ``pip install --no-index`` of the wheel
*with* its dependencies then resolves them against those packages: it checks that
pyproject.toml's ranges admit the pins of constraints.txt, and installs the wheel alone.  A full
``pip install .`` from the index fetches the same pins' releases and differs only in where they
lie (docs/development/testing.md).  The first run in the new environment compiles the numerical
core (its sources lie elsewhere: a fresh numba cache, here in the test's own directory): that
compile is most of the test's time (about a minute, several under load), and its progress lines
are part of what is checked.
"""

from __future__ import annotations

import os
import re
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT

#: The page whose output block of ``sappc simulate paper_tracking`` the installed run must print.
PAGE = ROOT / "docs" / "getting-started.md"
#: The longest the whole test may take [s] (the compile dominates).
TIMEOUT_S = 900
#: What the project's site-packages holds that belongs to this checkout's editable install.
EDITABLE = re.compile(r"^(__editable__\.sappc-.*|sappc-.*\.dist-info|__pycache__)$")


def _documented_metrics() -> list[str]:
    """The lines of the page's output block of the offline experiment, wall time left out."""
    text = PAGE.read_text()
    block = re.search(r"```text\n(scenario paper_tracking, controller sappc\n.*?)```", text, re.S)
    assert block is not None, f"{PAGE}: no output block of `sappc simulate paper_tracking`"
    return [ln for ln in block.group(1).splitlines() if not ln.strip().startswith("wall_time_s")]


def _project_site_packages() -> Path:
    paths = [Path(p) for p in site.getsitepackages() if Path(p).is_relative_to(sys.prefix)]
    assert paths, site.getsitepackages()
    return paths[0]


@pytest.mark.slow
def test_the_wheel_installed_outside_the_checkout_runs_the_paper_experiment_by_name(tmp_path: Path) -> None:
    # the wheel, from a copy of what the sdist holds (the checkout stays untouched by the build)
    src = tmp_path / "source"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(ROOT / "src", src / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    wheels = tmp_path / "wheels"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", str(wheels), str(src)],
                   check=True, capture_output=True, text=True, timeout=300)
    [wheel] = wheels.glob("sappc-*.whl")

    # a new environment; the project's packages reachable, its editable install not
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    new_site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                   check=True, capture_output=True, text=True).stdout.strip())
    deps = tmp_path / "deps"
    deps.mkdir()
    for entry in _project_site_packages().iterdir():
        if not EDITABLE.match(entry.name):
            (deps / entry.name).symlink_to(entry)
    (new_site / "_sappc_test_dependencies.pth").write_text(f"import site; site.addsitedir({str(deps)!r})\n")
    install = subprocess.run([*pip, "--python", str(python), "install", "--no-index", "--find-links", str(wheels), "sappc"],
                             capture_output=True, text=True, timeout=300)
    assert install.returncode == 0, install.stdout + install.stderr  # a pin outside its range fails here
    assert "Successfully installed sappc-" in install.stdout and wheel.name.startswith("sappc-"), install.stdout

    # run from elsewhere: nothing of the checkout on the path
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR", "VIRTUAL_ENV")}
    env.update(SAPPC_CACHE_DIR=str(tmp_path / "cache"), MPLBACKEND="Agg", PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}")

    def sappc(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(venv / "bin" / "sappc"), *args], cwd=elsewhere, env=env, capture_output=True, text=True, timeout=timeout)

    where = subprocess.run([str(python), "-c", "import sappc, sys; print(sappc.__file__); print(*sys.path, sep='\\n')"],
                           cwd=elsewhere, env=env, capture_output=True, text=True, check=True).stdout.splitlines()
    assert Path(where[0]).is_relative_to(new_site), where[0]
    assert not any(p.startswith(str(ROOT)) for p in where[1:]), where

    run = sappc("simulate", "paper_tracking", timeout=TIMEOUT_S)
    assert run.returncode == 0, run.stdout + run.stderr
    printed = [ln for ln in run.stdout.splitlines() if not ln.strip().startswith("wall_time_s")]
    assert printed == _documented_metrics(), run.stdout
    # the compile said what it did, and compiled what a one-run command calls only: the one-run loop, not the batch
    # loop nor the nodes' kernels
    assert "sappc: compiling the numerical core's loops once" in run.stderr, run.stderr
    assert "sappc: numerical core: the offline loop (one run) with sensor noise ready" in run.stderr, run.stderr
    assert "the controller's step" not in run.stderr and "(batches)" not in run.stderr, run.stderr
    # the compile's leaf process typed every leaf as the loop calls it (compiled_loop._leaf_calls; else it compiled them in vain)
    assert "unlike the loop" not in run.stderr, run.stderr

    # the bundled files: listed, copied out with the scenario they extend, and the copy loads as it is
    listed = sappc("scenarios")
    assert listed.returncode == 0 and re.search(r"(?m)^paper_tracking\s", listed.stdout), listed.stdout + listed.stderr
    copied = sappc("scenarios", "copy", "flight_gyro_bias_step", "mine")
    assert copied.returncode == 0, copied.stderr
    assert sorted(p.name for p in (elsewhere / "mine").iterdir()) == ["flight_gyro_bias_step.yaml", "paper_tracking_flight.yaml"]
    by_name, by_copy = sappc("params", "flight_gyro_bias_step", "--estimator"), sappc("params", "mine/flight_gyro_bias_step.yaml", "--estimator")
    assert by_name.returncode == by_copy.returncode == 0 and by_name.stdout == by_copy.stdout, by_name.stderr + by_copy.stderr
