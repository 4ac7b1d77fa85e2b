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
from collections.abc import Callable
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


def test_each_page_writes_into_directories_of_its_own() -> None:
    """A reader follows page after page in one checkout: a directory that two pages' commands
    write (an ``--out DIR``, or ``sappc report``'s default ``runs/report/<run>``) would refuse the
    second page's run or mix the two pages' results (issue 46: ``runs/exp1`` was three pages'
    three things, and the Foxglove tutorial's run was refused after getting started's)."""
    from sappc.files import bag_run_name, default_output_dir

    writers: dict[str, set[str]] = {}
    for page in PAGES:
        for b in blocks(page):
            if b.lang != "bash":
                continue
            for line in b.text.splitlines():
                outs = re.findall(r"--out[ =](\S+)", line)
                report = re.search(r"\b(?:sappcw?|sappc) report (\S+)", line)
                if report and not outs:
                    outs = [str(default_output_dir("report", bag_run_name(report.group(1))))]
                for out in outs:
                    writers.setdefault(out.rstrip("/"), set()).add(str(page.relative_to(ROOT)))
    shared = {d: sorted(p) for d, p in writers.items() if len(p) > 1}
    assert len(writers) > 20 and not shared, f"directories written by more than one page: {shared}"


#: Where a command on a page may write a file (``--out``, ``--json``, ``--results``, a ``>``): the one
#: output root, a temporary directory (a shell variable), stdout, and the committed results of
#: ``benchmarks/`` (what a measurement updates on purpose).
WRITABLE = re.compile(rf"^(?:{re.escape(str(OUTPUT_ROOT))}/|/tmp/|\"?\$|-$|/dev/null$|benchmarks/results_)")


def test_the_pages_write_only_under_runs_or_a_scratch_directory() -> None:
    """Issue 46: the momentum how-to wrote ``orbit.json`` and CONTRIBUTING ``m.json`` into the
    current directory, the checkout; every page (CONTRIBUTING's commands too) writes under
    ``runs/`` (ignored by git) or a temporary directory."""
    stray = []
    for page in [*PAGES, ROOT / "CONTRIBUTING.md", *sorted(p for p in (ROOT / "docs").rglob("*.md") if p not in PAGES)]:
        for b in blocks(page):
            if b.lang != "bash":
                continue
            for line in b.text.splitlines():
                command = re.split(r"\s#", line, maxsplit=1)[0]
                targets = re.findall(r"--(?:out|json|results)[ =](\S+)", command) + re.findall(r"(?<![\d&>])>>? *([^\s&]\S*)", command)
                stray += [f"{b.where()}: {t} ({command.strip()})" for t in targets if not WRITABLE.match(t)]
    assert not stray, "files written outside runs/:\n" + "\n".join(stray)


#: How a page states how long a command took on some machine: ``took 31 s``, ``23 s for the whole
#: command``, ``21 s for the study``, a printed ``wall 14.7 s``.  Such a figure goes stale with the
#: machine and the code, so a page quotes one only beside a link to the performance page, where
#: each is measured with its script, machine and date (or says where it was measured).
WALL_TIME = re.compile(r"\btook (?:about )?\d+(?:\.\d+)? ?(?:s|min)\b|\d+(?:\.\d+)? ?(?:s|min) for the (?:whole command|study)\b"
                       r"|\bwall \d+(?:\.\d+)? ?s\b")


def _unsourced(pages: list[Path], quote: re.Pattern[str], sourced: Callable[[str], bool], *, code: bool = True) -> list[str]:
    """Each match of ``quote`` in a paragraph of ``pages`` that ``sourced`` does not accept, with
    its page and context (``code``: fenced blocks are paragraphs too; else they are left out)."""
    unsourced = []
    for page in pages:
        text = page.read_text(encoding="utf-8")
        if not code:
            text = re.sub(r"(?ms)^```.*?^```", "", text)
        for para in re.split(r"\n\s*\n", text):
            flat = " ".join(para.split())
            for m in quote.finditer(flat):
                if not sourced(para):
                    unsourced.append(f"{page.relative_to(ROOT)}: ...{flat[max(0, m.start() - 60):m.end() + 20]}")
    return unsourced


def test_the_pages_quote_a_commands_time_only_with_its_measurement() -> None:
    unsourced = _unsourced(PAGES, WALL_TIME, lambda para: "performance.md" in para or "measured" in para.lower())
    assert not unsourced, "a command's time without the measurement it comes from:\n" + "\n".join(unsourced)


#: How a page quotes a figure of a command too long for the suite (the four controllers, or the
#: noise filters, over 100 noise seeds: ``p95 3.99e-5``, ``7.1 sign changes a second (median over
#: 100 seeds)``).  Such a figure goes stale with the code (issue 46: 3.956e-5 and 7.2 were quoted
#: where the code gave 3.985e-5 and 7.1), so a page quotes one only as a region that
#: ``benchmarks/published_figures.py`` writes from its record (``<!-- figure: KEY -->``,
#: ``<!-- figures: NAME -->``), and the record is checked against the code below.
PUBLISHED_FIGURE = re.compile(r"\bp95\b[^|.;]*?\d|\bmedian over 100\b|\bover 100 (?:noise )?seeds\b")


def _published_figures():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("_published_figures", ROOT / "benchmarks" / "published_figures.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_the_pages_quote_a_long_commands_figures_only_as_its_record_gives() -> None:
    figures = _published_figures()
    record = figures.load()
    assert not figures.stale_pages(record), "pages whose published figures are not the record's: python benchmarks/published_figures.py --write"
    unmarked = _unsourced(figures.PAGES, PUBLISHED_FIGURE, lambda para: "<!-- figure" in para, code=False)
    assert not unmarked, "a long command's figure not written from its record (benchmarks/published_figures.py):\n" + "\n".join(unmarked)
    regions = "".join(p.read_text(encoding="utf-8") for p in figures.PAGES)
    for name in figures.RENDERERS:  # every region is on a page, and the pages name the commands that measured them
        assert f"<!-- figures: {name} -->" in regions, name
    noise = (ROOT / "docs" / "design" / "noise.md").read_text(encoding="utf-8")
    for command in figures.COMMANDS.values():
        assert command.split(" --out")[0] in noise, command


@pytest.mark.slow
def test_the_published_figures_record_is_what_the_code_gives(tmp_path: Path) -> None:
    """The record of ``benchmarks/published_figures.py`` was measured by its commands: the
    comparison, run again (12 to 30 s), gives its table exactly, written as the how-to shows it;
    the sweep's first runs, recomputed (two runs of each of its 27 points, about 10 s: the whole
    sweep takes one to two and a half minutes), give every recorded metric bit for bit. A change
    of the code that moves the published figures fails here (then ``--measure`` and ``--write``)."""
    import numpy as np

    figures = _published_figures()
    record = figures.load()
    summary = figures.comparison(figures.SEEDS, tmp_path / "comparison")
    assert summary["table"] == record["sources"]["flight_comparison"]["table"]
    written = (tmp_path / "comparison" / "comparison.md").read_text().splitlines()[2:]
    assert figures._controller_table(record).splitlines() == written
    runs = record["slice_runs"]
    sweep = figures.sweep_slice_runs(figures.bench_noise_filter(), runs)
    recorded = record["sources"]["noise_filter_sweep"]["slice"]
    assert [(p["curve"], p["cutoff"]) for p in sweep] == [(p["curve"], p["cutoff"]) for p in recorded]
    for point, expected in zip(sweep, recorded):
        for name in ("qev", "sign", "overshoot", "settling_s"):
            np.testing.assert_array_equal(point[name], expected[name], err_msg=f"noise filter sweep, {point['curve']} {point['cutoff']}, {name}")
