"""The files ``sappc`` reads and writes by default: the data installed with the package, and
the one directory its commands write into when not told where.

Bundled data: the scenarios, the nodes' parameter files and the Foxglove layout
(``src/sappc/data/``; the checkout's ``config/`` is a link to it).

A command that takes a scenario accepts a file or the name of a bundled scenario
(:func:`scenario_path`): ``sappc simulate paper_tracking`` runs
``<package>/data/scenarios/paper_tracking.yaml`` from any directory, with or without a
checkout.  ``sappc scenarios`` lists them (:func:`bundled_scenarios`) and
``sappc scenarios copy NAME [DEST]`` copies one out to edit (:func:`copy_scenario`), with the
files it ``extends`` so that the copy loads as it is.

Outputs: a command given no output directory writes into
``runs/<command>/<name>`` under the working directory (:func:`default_output_dir`; ``runs/`` is
ignored by git in the checkout), e.g. ``runs/run/paper_tracking-sappc-20260101-120000`` for
``sappc run`` and ``runs/report/paper_tracking-sappc-20260101-120000`` for the report of its bag.
"""

from __future__ import annotations

import shutil
import stat
from dataclasses import dataclass
from pathlib import Path

from gnc_common.validation import ConfigError, did_you_mean, quoted, read_yaml_file

__all__ = ["DATA_DIR", "OUTPUT_ROOT", "SCENARIOS_DIR", "BundledScenario", "bag_run_name", "bundled_scenarios", "copy_scenario",
           "default_output_dir", "extends_chain", "scenario_path"]

#: The package's data directory (plain files on disk: a zipped install is not supported).
DATA_DIR = Path(__file__).resolve().parent / "data"
#: The bundled scenarios.
SCENARIOS_DIR = DATA_DIR / "scenarios"
#: The extension of a scenario file.
SUFFIX = ".yaml"
#: Where commands write when given no directory (relative to the working directory).
OUTPUT_ROOT = Path("runs")


def default_output_dir(command: str, name: str) -> Path:
    """``runs/<command>/<name>``: where ``sappc <command>`` writes when given no directory."""
    return OUTPUT_ROOT / command / name


def bag_run_name(bag: str | Path) -> str:
    """A short name for the run a bag holds: the run directory's name for ``<run>/bag`` (as
    ``sappc run`` writes it), else the bag's own name without ``.mcap``."""
    p = Path(str(bag).rstrip("/") or ".").resolve()
    if p.suffix == ".mcap":
        p = p.with_suffix("") if p.parent.name != "bag" else p.parent
    return p.parent.name if p.name == "bag" and p.parent.name else p.name


@dataclass(frozen=True)
class BundledScenario:
    """One bundled scenario: its name (the file's stem), file, one-line description and the
    scenario it extends (``None``: none)."""

    name: str
    path: Path
    description: str
    extends: str | None


def _names() -> list[str]:
    return sorted(p.stem for p in SCENARIOS_DIR.glob(f"*{SUFFIX}"))


def bundled_scenarios() -> list[BundledScenario]:
    """Every bundled scenario, by name."""
    out = []
    for name in _names():
        path = SCENARIOS_DIR / f"{name}{SUFFIX}"
        data = read_yaml_file(path, "scenario")
        base = data.get("extends")
        out.append(BundledScenario(name, path, " ".join(str(data.get("description", "")).split()),
                                   Path(base).stem if isinstance(base, str) else None))
    return out


def scenario_path(scenario: str | Path) -> Path:
    """The file of ``scenario``: a path to an existing file as it is, else the bundled scenario of
    that name (``paper_tracking`` or ``paper_tracking.yaml``).

    Raises
    ------
    ConfigError
        When ``scenario`` is neither, naming it and the bundled names; when it is a path that exists
        but is not a regular file (a directory, a pipe such as ``/dev/fd/N``, a device), saying what it is.
    """
    p = Path(scenario)
    if p.is_file():
        return p
    name = p.name[: -len(SUFFIX)] if p.name.endswith(SUFFIX) else p.name
    if str(p) == p.name and name in _names():  # a bare name, not a path to a file that is missing
        return SCENARIOS_DIR / f"{name}{SUFFIX}"
    what = _not_a_file(p)
    if what:  # it exists: say what it is, not that it is missing
        twice = "" if what == "a directory" else " (sappc run reads the scenario twice, which a pipe or a device does not allow)"
        raise ConfigError(f"scenario {_quoted_path(scenario)} is {what}, not a file: give a scenario file{twice}")
    what = "no such file" if str(p) != p.name else "no such file, and no bundled scenario of that name" + did_you_mean(name, _names())
    raise ConfigError(f"scenario {_quoted_path(scenario)}: {what} (bundled: {', '.join(_names())}; "
                      "`sappc scenarios` lists them)")


#: What a path that exists but is not a regular file is, by its ``stat`` file type.
_FILE_TYPES = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a pipe (a FIFO, or /dev/fd/N of a process substitution)"),
               (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _not_a_file(p: Path) -> str:
    """What ``p`` is when it exists (its link followed) but is not a regular file; ``""`` otherwise."""
    try:
        mode = p.stat().st_mode
    except (OSError, ValueError):  # missing, a dangling link, unreadable, or a name the system refuses
        return ""
    return next((what for test, what in _FILE_TYPES if test(mode)), "" if stat.S_ISREG(mode) else "not a regular file")


def _quoted_path(scenario: str | Path) -> str:
    """The path or name as given, quoted for a message (a long one cut)."""
    return quoted(str(scenario), 160)


def extends_chain(path: Path) -> list[Path]:
    """``path`` and the files it ``extends``, in that order (each relative to the one before).

    Raises
    ------
    ConfigError
        When a file of the chain is missing or the chain comes back to a file in it.
    """
    chain = [path]
    while True:
        data = read_yaml_file(chain[-1], "scenario")
        base = data.get("extends") if isinstance(data, dict) else None
        if not isinstance(base, str):
            return chain
        nxt = (chain[-1].parent / base).resolve()
        if nxt in [c.resolve() for c in chain]:
            raise ConfigError(f"{chain[-1]}: extends: {base} comes back to a file already extended ({nxt})")
        chain.append(nxt)


def copy_scenario(name: str, dest: str | Path = ".", *, force: bool = False) -> list[Path]:
    """Copy the bundled scenario ``name`` into the directory ``dest`` (created if missing), with the
    files it ``extends`` beside it under their own names, so that the copy loads as it is; return
    the files written.

    Raises
    ------
    ConfigError
        When ``name`` is not a bundled scenario, ``dest`` is a file, or (without ``force``) a file
        to write exists already.
    """
    bare = name[: -len(SUFFIX)] if name.endswith(SUFFIX) else name
    if bare not in _names():
        raise ConfigError(f"no bundled scenario {name!r}{did_you_mean(bare, _names())} (bundled: {', '.join(_names())})")
    out_dir = Path(dest)
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(f"DEST {str(dest)!r} is a file: give a directory (the scenario keeps its name, {bare}{SUFFIX})")
    chain = extends_chain(SCENARIOS_DIR / f"{bare}{SUFFIX}")
    targets = [out_dir / src.name for src in chain]
    existing = [t for t in targets if t.exists()]
    if existing and not force:
        raise ConfigError(f"{existing[0]} exists already; give another DEST, or --force to overwrite it")
    out_dir.mkdir(parents=True, exist_ok=True)
    for src, target in zip(chain, targets):
        shutil.copyfile(src, target)
    return targets
