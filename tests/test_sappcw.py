"""``./sappcw``'s set-up, on a stand-in Python whose pip and compile take seconds and print
little (as the real ones do): every step is announced and ends with its time, a progress line
comes at least every ``SAPPCW_TICK_S`` + 1 seconds of quiet (the real set-up, with 8, prints at
least every 10 s: docs/getting-started.md has a measured run), pip's progress counts the packages
against constraints.txt, the compile's own lines are passed on, a failed step shows the end of
its output, and a set-up environment is not set up again.  The real set-up, from nothing, is
measured by hand (docs/getting-started.md): it takes minutes and the network."""

from __future__ import annotations

import re
import shutil
import subprocess
import time
from pathlib import Path

from conftest import ROOT

#: The quiet time before a progress line in these tests [s].
TICK_S = 2
#: The stand-in ``python``: a venv of itself, a slow pip, a slow compile, a ``sappc``.
STUB = r"""#!/usr/bin/env bash
here="$(cd "$(dirname "$0")" && pwd)"
case "$*" in
  --version) echo "Python 3.11.7" ;;
  "-c import sys"*) exit 0 ;;
  "-m venv "*) mkdir -p "$3/bin" && cp "$0" "$3/bin/python" && printf '#!/usr/bin/env bash\necho "sappc stub $*"\n' > "$3/bin/sappc" \
               && chmod +x "$3/bin/sappc"; sleep 1 ;;
  *"pip==25.3"*) echo "Collecting pip==25.3"; sleep 1; echo "Successfully installed pip-25.3" ;;
  *"-c "*"constraints.txt"*)
      [ -n "${STUB_PIP_FAILS:-}" ] && { echo "Collecting numpy"; echo "ERROR: no matching distribution for numpy"; exit 1; }
      for p in numpy scipy pyyaml; do echo "Collecting $p"; sleep 1; done
      echo "Processing /opt/pypi/files/numba-0.68.1.whl (from sappc==0.1.0)"; sleep 3
      echo "Installing collected packages: numpy, scipy, pyyaml, numba"; sleep 5
      echo "Successfully installed numpy scipy pyyaml numba" ;;
  *warm_up*) echo "sappc: numerical core: the set-up kernels ready (1 s)"; sleep 6
             echo "sappc: numerical core: the controller's step ready (7 s)" ;;
  *) echo "stub python: unexpected arguments: $*" >&2; exit 3 ;;
esac
"""


def _checkout(tmp_path: Path) -> Path:
    """A directory with sappcw, pyproject.toml and constraints.txt, and the stand-in Python."""
    root = tmp_path / "checkout"
    root.mkdir()
    for name in ("sappcw", "pyproject.toml", "constraints.txt"):
        shutil.copy2(ROOT / name, root / name)
    stub = tmp_path / "python-stub"
    stub.write_text(STUB)
    stub.chmod(0o755)
    return root


def _run(root: Path, tmp_path: Path, **env: str) -> tuple[int, list[tuple[float, str]]]:
    """Run ``./sappcw --version``; (exit status, [(seconds since the start, line) of stderr and stdout])."""
    import os

    start = time.monotonic()
    proc = subprocess.Popen([str(root / "sappcw"), "--version"], cwd=root, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env={**os.environ, "SAPPC_PYTHON": str(tmp_path / "python-stub"), "SAPPCW_TICK_S": str(TICK_S), **env})
    assert proc.stdout is not None
    lines = [(time.monotonic() - start, line.rstrip("\n")) for line in proc.stdout]
    return proc.wait(timeout=120), lines


def test_the_set_up_announces_each_step_and_never_stays_quiet_longer_than_a_tick(tmp_path: Path) -> None:
    root = _checkout(tmp_path)
    status, lines = _run(root, tmp_path)
    text = "\n".join(f"{t:5.1f} {line}" for t, line in lines)
    assert status == 0, text
    times = [0.0] + [t for t, _ in lines]
    assert max(b - a for a, b in zip(times, times[1:])) <= TICK_S + 1.5, text
    said = [line for _, line in lines]
    pins = sum(1 for ln in (ROOT / "constraints.txt").read_text().splitlines() if re.match(r"[A-Za-z0-9]", ln))
    assert said[0] == f"sappcw: setting up {root / '.venv'} with Python 3.11.7: {pins} pinned packages, then the numerical core's compile"
    assert said[1].startswith("sappcw:   first set-up: about ")
    for step in ("1/4 venv", "2/4 pip", "3/4 dependencies", "4/4 numerical core (compiled once)"):
        assert any(re.fullmatch(rf"sappcw:   {re.escape(step)}: done in \d+ s", s) for s in said), (step, text)
    assert any(re.fullmatch(rf"sappcw:   3/4 dependencies: [1-4] of about {pins} packages resolved and fetched \(\d+ s\)", s) for s in said), text
    assert any(re.fullmatch(r"sappcw:   3/4 dependencies: installing the 4 packages into the venv \(\d+ s\)", s) for s in said), text
    assert "    sappc: numerical core: the set-up kernels ready (1 s)" in said and "    sappc: numerical core: the controller's step ready (7 s)" in said
    assert re.fullmatch(r"sappcw: set-up done in \d+ s", said[-2]) and said[-1] == "sappc stub --version", text
    assert not (root / ".venv" / "setup-log").exists()

    again_status, again = _run(root, tmp_path)  # set up: the command runs at once
    assert again_status == 0 and [line for _, line in again] == ["sappc stub --version"]


def test_a_failed_step_shows_the_end_of_its_output_and_where_the_rest_is(tmp_path: Path) -> None:
    root = _checkout(tmp_path)
    status, lines = _run(root, tmp_path, STUB_PIP_FAILS="1")
    said = [line for _, line in lines]
    assert status == 1, said
    assert "    ERROR: no matching distribution for numpy" in said
    log = root / ".venv" / "setup-log" / "3_4_dependencies.log"
    assert re.fullmatch(rf"sappcw: 3/4 dependencies failed after \d+ s; the whole output is in {re.escape(str(log))}", said[-1]), said
    assert "ERROR: no matching distribution" in log.read_text()
    assert not (root / ".venv" / ".sappc-stamp").exists()  # the next call sets up again


def test_the_getting_started_sample_shows_the_set_ups_own_steps_and_pin_count() -> None:
    """docs/getting-started.md shows the set-up's output: its steps are the script's, numbered
    of as many as it has, the page names how many, and the packages are constraints.txt's pins
    (issue 46: the page said 165 packages and three steps when there were 161 and four)."""
    page = (ROOT / "docs" / "getting-started.md").read_text()
    script = (ROOT / "sappcw").read_text()
    steps = re.findall(r'step "(\d+)/(\d+) ([^"]+)"', script)
    assert steps and {int(n) for _, n, _ in steps} == {len(steps)} and [int(k) for k, _, _ in steps] == list(range(1, len(steps) + 1))
    sample = page.split("```text\nsappcw: setting up", 1)[1].split("```", 1)[0]
    shown = dict.fromkeys(re.findall(r"(?m)^sappcw:   (\d+/\d+ [^:]+):", sample))
    assert list(shown) == [f"{k}/{n} {name}" for k, n, name in steps], list(shown)
    words = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six"}
    assert f"The set-up prints its {words[len(steps)]} steps" in page
    pins = sum(1 for ln in (ROOT / "constraints.txt").read_text().splitlines() if re.match(r"[A-Za-z0-9]", ln))
    counts = {int(a or b) for a, b in re.findall(r"(\d+) pinned packages|of about (\d+) packages", sample)}
    assert counts == {pins}, (counts, pins)
