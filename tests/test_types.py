"""The type check of ``src/``: ``mypy --strict`` with the configuration in ``pyproject.toml``
(``[tool.mypy]``), run by the README's test command (./sappcw test -q) and so in CI.  Zero errors.

mypy comes with the ``test`` extra (pinned there); the test is never skipped: without mypy it
fails.  The incremental cache is mypy's default ``.mypy_cache`` in the repository root (ignored by
git), shared with a manual ``mypy`` run: a fresh check takes about 15 s, a cached one about 1 s.
"""

from __future__ import annotations

import subprocess
import sys

from conftest import ROOT


def test_mypy_strict_reports_no_errors_in_src() -> None:
    proc = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml")],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, f"mypy exited with status {proc.returncode}:\n{proc.stdout}{proc.stderr}"
