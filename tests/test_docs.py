"""The documentation: the site builds with warnings as errors, the README stays short, and every
code block of the README and of the user pages runs, so that no snippet can rot.

Each page's blocks run in order in a scratch directory of their own, as a reader following the
page would: ``config/``, ``examples/``, ``src/``, ``benchmarks/`` and ``.venv`` point at the
checkout, ``./sappcw`` runs ``sappc`` from this test's environment, and ``short/`` holds every
scenario of ``config/scenarios/`` cut to :data:`SHORT_DURATION_S`.

- ``bash`` blocks run with ``set -e``; ``python`` blocks in a fresh interpreter; a ``text`` block
  after ``<!-- doctest: output -->`` must equal the output of the block before it; ``yaml`` blocks
  must parse, and after ``<!-- doctest: scenario-fragment -->`` must load when merged into
  ``config/scenarios/paper_tracking.yaml``; other ``text`` blocks are shown output, not run.
- Comment lines right before a block change how it runs (CONTRIBUTING.md, "Code blocks in the
  documentation"): ``skip (why)``, ``replace "A" -> "B" (why)``, ``status N ... (why)``,
  ``needs MODULE``.  ``<!-- walkthrough: ... -->`` blocks are run by
  ``tests/tools/graph/test_walkthrough.py``.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

from conftest import ROOT
from sappc.files import OUTPUT_ROOT

#: The README's budget [bytes]: what a newcomer reads in five minutes, as the READMEs of the
#: field's well-liked projects (rosbags, mcap, Basilisk, python-control: 5 to 15 KB).
README_MAX_BYTES = 15_000
#: Duration of the ``short/`` scenarios [s]: a run through the graph with every node and a bag
#: (200 samples at 100 Hz); the graph's start and stop cost more than its samples.
SHORT_DURATION_S = 2.0
#: Longest one block may run [s] (the longest, a 12-trial tuning study, takes about 10 s here).
BLOCK_TIMEOUT_S = 600
#: The pages whose code blocks run: what a user copies from.
PAGES = [ROOT / "README.md", ROOT / "docs" / "getting-started.md",
         *sorted((ROOT / "docs" / "tutorials").glob("*.md")), *sorted((ROOT / "docs" / "how-to").glob("*.md"))]
#: Block languages that run, and those that are shown (output, synopses).
RUN, SHOWN = {"bash", "python", "yaml"}, {"text", ""}
DIRECTIVE = re.compile(r"^<!-- (doctest|walkthrough): (.*) -->$")
KNOWN = ("skip", "replace", "status", "needs", "output", "scenario-fragment")


@dataclass
class Block:
    page: Path
    line: int  # of the opening fence, 1-based
    lang: str
    text: str
    directives: list[str] = field(default_factory=list)
    walkthrough: bool = False

    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"

    def directive(self, name: str) -> str | None:
        return next((d[len(name):].strip() for d in self.directives if d.split(" ", 1)[0] == name), None)


def blocks(page: Path) -> list[Block]:
    """The fenced code blocks of ``page``, each with the directives on the lines right above it."""
    lines = page.read_text(encoding="utf-8").splitlines()
    out: list[Block] = []
    i = 0
    while i < len(lines):
        if not lines[i].startswith("```"):
            i += 1
            continue
        lang, start = lines[i][3:].strip(), i
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        block = Block(page, start + 1, lang, "\n".join(lines[start + 1:end]) + "\n")
        k = start - 1
        while k >= 0 and (m := DIRECTIVE.match(lines[k].strip())):
            if m.group(1) == "walkthrough":
                block.walkthrough = True
            else:
                block.directives.insert(0, m.group(2))
            k -= 1
        out.append(block)
        i = end + 1
    return out


def _replacements(block: Block) -> list[tuple[str, str]]:
    return [(a, b) for d in block.directives if d.startswith("replace") for a, b in re.findall(r'"([^"]*)" -> "([^"]*)"', d)]


#: What :func:`_workdir` puts into a page's scratch directory (the checkout's, as links; the test's own).
_SCRATCH_ENTRIES = {"config", "examples", "src", "benchmarks", "docs", ".venv", "short", "sappcw"}


def _workdir(tmp: Path) -> Path:
    """The scratch directory a page's blocks run in."""
    for name in ("config", "examples", "src", "benchmarks", "docs"):
        (tmp / name).symlink_to(ROOT / name)
    (tmp / ".venv").symlink_to(Path(sys.prefix))
    short = tmp / "short"
    short.mkdir()
    for scenario in sorted((ROOT / "config" / "scenarios").glob("*.yaml")):
        text = re.sub(r"(?m)^duration_s:.*$", f"duration_s: {SHORT_DURATION_S}", scenario.read_text())
        # a 2 s cut cannot show what the whole run promises (it ends before t2): no requirements
        # (the loss-of-control rule still applies; it judges nothing before the steady window)
        text = re.sub(r"(?m)^metrics:\n(?=\S|\Z)", "", re.sub(r"(?m)^  requirements:.*\n(?:    .*\n)*", "", text))
        (short / scenario.name).write_text(text)
    shim = tmp / "sappcw"
    shim.write_text(
        "#!/usr/bin/env bash\n"
        "# the project's entry point, on this test's environment\n"
        "set -euo pipefail\n"
        f'exec {shlex.quote(sys.executable)} -m sappc "$@"\n')
    shim.chmod(0o755)
    return tmp


def _environment() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"  # `python`, `sappc`: this environment's
    env["MPLBACKEND"] = "Agg"
    env["NO_MKDOCS_2_WARNING"] = "1"
    return env


def _run(block: Block, text: str, cwd: Path) -> str:
    """Run one block; return its output (stdout and stderr), failing the test with both on error."""
    if block.lang == "python":
        cmd, allowed = [sys.executable, "-"], {0}
    else:
        status = block.directive("status")
        allowed = {0} if status is None else {int(s) for s in re.findall(r"^\d+(?:\s+\d+)*", status)[0].split()}
        cmd = ["bash", "-o", "pipefail", "-c", text] if status is not None else ["bash", "-e", "-o", "pipefail", "-c", text]
    proc = subprocess.run(cmd, input=text if block.lang == "python" else None, cwd=cwd, env=_environment(), text=True,
                          capture_output=True, timeout=BLOCK_TIMEOUT_S)
    if proc.returncode not in allowed:
        pytest.fail(f"{block.where()}: exit status {proc.returncode} (allowed {sorted(allowed)})\n--- block\n{text}"
                    f"--- stdout\n{proc.stdout[-4000:]}\n--- stderr\n{proc.stderr[-4000:]}", pytrace=False)
    return proc.stdout


def _check_yaml(block: Block, text: str) -> None:
    data = yaml.safe_load(text)
    if block.directive("scenario-fragment") is None:
        return
    from sappc.montecarlo.config import campaign_config
    from sappc.montecarlo.tuning import tuning_config
    from sappc.scenario import scenario_from_mapping

    base = yaml.safe_load((ROOT / "config" / "scenarios" / "paper_tracking.yaml").read_text())
    scenario = scenario_from_mapping({**base, **data}, source=block.where())
    if "montecarlo" in data:
        campaign_config(scenario)
    if "tuning" in data:
        tuning_config(scenario)


def test_the_readme_is_short() -> None:
    size = len((ROOT / "README.md").read_bytes())
    assert size <= README_MAX_BYTES, f"README.md is {size} bytes; move detail into docs/ (budget {README_MAX_BYTES})"


def test_the_readmes_links_lead_somewhere() -> None:
    """README.md is read on the forge, outside the site: its relative links must name files."""
    text = (ROOT / "README.md").read_text()
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    missing = [link for link in links if "://" not in link and not (ROOT / link).exists()]
    assert links and not missing, missing


def test_every_directive_is_known_and_every_skip_says_why() -> None:
    skips = []
    for page in PAGES:
        for b in blocks(page):
            for d in b.directives:
                assert d.split(" ", 1)[0] in KNOWN, f"{b.where()}: unknown directive {d!r}"
                if d.startswith(("skip", "replace", "status")):
                    assert re.search(r"\(.+\)", d), f"{b.where()}: {d!r} says no reason in brackets"
            if b.directive("skip") is not None or b.walkthrough:
                skips.append(b.where())
            assert b.lang in RUN | SHOWN, f"{b.where()}: a {b.lang!r} block: mark it bash, python, yaml or text"
    assert len(skips) <= 12, f"too many skipped blocks: {skips}"  # rare, each with its reason


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_every_code_block_of_the_page_runs(page: Path, tmp_path: Path) -> None:
    cwd = _workdir(tmp_path)
    last_output: str | None = None
    for b in blocks(page):
        if b.walkthrough or b.directive("skip") is not None:
            continue
        if b.lang in SHOWN:
            if b.directive("output") is not None:
                assert last_output is not None, f"{b.where()}: an output block after no block that ran"
                assert last_output.rstrip() == b.text.rstrip(), f"{b.where()}: the block before printed\n{last_output}"
            continue
        needs = b.directive("needs")
        if needs and importlib.util.find_spec(needs) is None:
            continue  # e.g. Basilisk, an optional extra: its own tests are skipped the same way
        text = b.text
        for old, new in _replacements(b):
            assert old in text, f"{b.where()}: replace {old!r}: not in the block"
            text = text.replace(old, new)
        if b.lang == "yaml":
            _check_yaml(b, text)
        else:
            last_output = _run(b, text, cwd)
    # what a reader following the page leaves in the checkout: nothing git sees, only OUTPUT_ROOT (ignored)
    written = sorted(p.name for p in cwd.iterdir() if p.name not in _SCRATCH_ENTRIES)
    assert set(written) <= {str(OUTPUT_ROOT)}, f"{page.relative_to(ROOT)}: its blocks wrote {written} outside {OUTPUT_ROOT}/, the one output root"


def test_the_site_builds_with_warnings_as_errors(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, env=_environment(), capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-8000:]
    for page in ("reference/cli", "reference/nodes", "reference/scenario", "reference/topics", "reference/api/sappc"):
        assert (tmp_path / "site" / page / "index.html").stat().st_size > 10_000, page  # the generated parts are there


def _generators():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("docs_reference", ROOT / "docs" / "_hooks" / "reference.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_references_cover_every_command_node_key_and_topic() -> None:
    """What the reference pages are generated from is everything the code has."""
    ref = _generators()
    import sappc.cli
    import sappc_msgs_py.contract as contract

    cli = ref.gen_cli()
    for name, _, sub in ref._subcommands(sappc.cli._parser()):
        assert f"## sappc {name}" in cli
        section = cli.split(f"## sappc {name}\n", 1)[1].split("\n## ", 1)[0]
        for status, _ in sappc.cli.EXIT_STATUSES[name]:  # each command's exit statuses, under its heading
            assert f"| `{status}` |" in section.split("Exit status:", 1)[1], (name, status)
        for nested, _, _ in ref._subcommands(sub):
            assert f"`sappc {name} {nested}`" in section, (name, nested)
    commands = {cls.COMMAND for cls in ref.node_classes()}
    assert {"python -m sappc_controller", "python -m spacecraft_sim", "python -m spacecraft_sim.reference",
            "python -m spacecraft_sim.disturbance", "python -m sappc.graph.recorder"} <= commands
    topics = ref.gen_topics()
    for t in contract.TOPICS:
        assert f"| `{t.name}` |" in topics
    scenario = ref.gen_scenario()
    for key in ("`controllers.sappc.rpf`", "`montecarlo.dispersions.hardware`", "`tuning.requirements`", "`actuator.wheels`"):
        assert key in scenario
    with pytest.raises(ref.GenerationError, match="unknown generator"):
        ref.expand("<!-- generate: nothing -->")


def test_the_cli_reference_shows_what_help_shows_and_every_argument_has_a_meaning() -> None:
    """No argparse marker and no hidden option on the page, a meaning for every argument, and
    each (nested) command's usage names its own path once (``sappc scenarios copy [-h] ...``)."""
    ref = _generators()
    import argparse

    import sappc.cli

    cli = ref.gen_cli()
    assert "SUPPRESS" not in cli
    assert "--plots" not in cli  # simulate's deprecated alias: --help hides it, so does the page
    rows = [line for line in cli.splitlines() if line.startswith("| `") and not line.startswith("| [")]
    arguments = [r for r in rows if not re.match(r"^\| `\d+` \|", r)]  # not the exit-status rows
    assert len(arguments) > 40
    for row in arguments:
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", row)[1:-1]]
        assert len(cells) == 2 and cells[1] and cells[1] != ".", row
    usages = re.findall(r"```text\n(.*)\n```", cli)
    for name, _, sub in ref._subcommands(sappc.cli._parser()):
        assert any(u.startswith(f"sappc {name} [-h]") for u in usages), name
        for nested, _, _ in ref._subcommands(sub):
            mine = [u for u in usages if u.startswith(f"sappc {name} {nested} ")]
            assert len(mine) == 1 and mine[0].startswith(f"sappc {name} {nested} [-h]") and mine[0].count(f" {nested} ") == 1, usages
    with pytest.raises(ref.GenerationError, match="has no help"):
        bare = argparse.ArgumentParser(prog="sappc x")
        bare.add_argument("thing")
        ref._argument_rows(bare)


#: How a page states how long a command took on some machine: ``took 31 s``, ``23 s for the whole
#: command``, ``21 s for the study``, a printed ``wall 14.7 s``.  Such a figure goes stale with the
#: machine and the code, so a page quotes one only beside a link to the performance page, where
#: each is measured with its script, machine and date (or says where it was measured).
WALL_TIME = re.compile(r"\btook (?:about )?\d+(?:\.\d+)? ?(?:s|min)\b|\d+(?:\.\d+)? ?(?:s|min) for the (?:whole command|study)\b"
                       r"|\bwall \d+(?:\.\d+)? ?s\b")


def test_the_pages_quote_a_commands_time_only_with_its_measurement() -> None:
    unsourced = []
    for page in PAGES:
        for para in re.split(r"\n\s*\n", page.read_text(encoding="utf-8")):
            flat = " ".join(para.split())
            for m in WALL_TIME.finditer(flat):
                if "performance.md" not in para and "measured" not in para.lower():
                    unsourced.append(f"{page.relative_to(ROOT)}: ...{flat[max(0, m.start() - 60):m.end() + 20]}")
    assert not unsourced, "a command's time without the measurement it comes from:\n" + "\n".join(unsourced)
