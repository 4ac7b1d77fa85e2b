"""The small bad YAML files of issue 46, item 3, written for the tests and the benchmark that
feed them to every command that reads YAML (``tests/tools/test_yaml_limits.py``,
``benchmarks/bench_yaml_limits.py``).

Before the loader's limits (:func:`gnc_common.validation.safe_load_yaml`), ``sappc simulate``
(docs/performance.md, "Bad YAML files"): ``brackets_30000`` ended in a segmentation fault (exit
139, no message), ``open_brackets_1000`` in a 4,002-line ``RecursionError`` traceback,
``q_BN_400_deep`` in a traceback from ``gnc_common/validation.py`` (``sappc run``: exit 1),
``aliases_6_levels`` answered after 2.5 s and 332 MB with a message of 39 MB, and
``aliases_8_levels`` was still running after 75 s.
"""

from __future__ import annotations

from pathlib import Path

#: Which limit of :mod:`gnc_common.validation` refuses each file.
LIMIT = {
    "brackets_30000": "MAX_YAML_DEPTH",
    "open_brackets_1000": "MAX_YAML_DEPTH",
    "q_BN_400_deep": "MAX_YAML_DEPTH",
    "aliases_6_levels": "MAX_YAML_NODES",
    "aliases_8_levels": "MAX_YAML_NODES",
}


#: Every command that reads a YAML file a user names, with the arguments that make it read
#: ``FILE`` (a bare file name in the working directory; ``BAG`` a bag that records nothing of it).
COMMANDS: dict[str, tuple[str, ...]] = {
    "simulate": ("simulate", "FILE"),
    "run": ("run", "FILE"),
    "params": ("params", "FILE"),
    "montecarlo": ("montecarlo", "FILE", "--runs", "2"),
    "tune": ("tune", "FILE"),
    "compare-controllers": ("compare-controllers", "FILE"),
    "report --scenario": ("report", "BAG", "--scenario", "FILE", "--out", "report"),
    "rerun --params": ("rerun", "BAG", "--params", "FILE"),
}
#: The bag ``BAG`` of :data:`COMMANDS` names, as :func:`write_bad_yaml` writes it.
BAG = "one_clock.mcap"

#: Runs the command of its arguments and writes to the first argument the command's peak resident
#: memory [KiB] and the CPU time it took [s]: in a process of its own, the command is its only child.
MEASURE = ("import resource, subprocess, sys\n"
           "rc = subprocess.call(sys.argv[2:])\n"
           "u = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
           "open(sys.argv[1], 'w').write(f'{u.ru_maxrss} {u.ru_utime + u.ru_stime}')\n"
           "sys.exit(rc if rc >= 0 else 128 - rc)\n")


def command_args(command: str, name: str) -> list[str]:
    """The arguments of ``command`` (a key of :data:`COMMANDS`) on the file ``name``."""
    return [{"FILE": f"{name}.yaml", "BAG": BAG}.get(a, a) for a in COMMANDS[command]]


def _aliases(levels: int, per_level: int = 10) -> str:
    """A scenario whose ``q_BN`` holds a chain of anchors, each a list of ``per_level`` aliases of
    the one before: ``per_level ** levels`` strings once expanded, in a few hundred bytes."""
    items = ['&a0 "lol lol lol lol lol lol lol lol"']
    items += [f"&a{k} [" + ", ".join([f"*a{k - 1}"] * per_level) + "]" for k in range(1, levels + 1)]
    return "extends: paper_tracking.yaml\ninitial_state:\n  q_BN: [" + ", ".join(items) + "]\n"


def bad_yaml_texts() -> dict[str, str]:
    """The files' texts by name (the keys of :data:`LIMIT`)."""
    quaternion = "[" * 399 + "[0.3254, 0.4068, -0.3254, 0.7891]" + "]" * 399
    return {
        "brackets_30000": "notes: " + "[" * 30_000 + "]" * 30_000 + "\n",  # 60 kB
        "open_brackets_1000": "notes: " + "[" * 1000 + "\n",  # 1 kB, never closed
        "q_BN_400_deep": f"extends: paper_tracking.yaml\ninitial_state:\n  q_BN: {quaternion}\n  omega_BN_B_rad_s: [0.0, 0.0, 0.0]\n",
        "aliases_6_levels": _aliases(6),
        "aliases_8_levels": _aliases(8),
    }


def write_bad_yaml(directory: Path) -> dict[str, Path]:
    """Write each file as ``<name>.yaml`` into ``directory``, and :data:`BAG` (one clock message,
    written with the ``mcap`` package's writer: ``tests/bagmaker.py``); return the files by name."""
    from bagmaker import write_bag
    from sappc_msgs_py.contract import CLOCK
    from sappc_msgs_py.convert import clock_msg

    paths = {}
    for name, text in bad_yaml_texts().items():
        paths[name] = directory / f"{name}.yaml"
        paths[name].write_text(text)
    write_bag(directory / BAG, [(CLOCK.name, CLOCK.type_name, clock_msg(0.0), 0)])
    return paths
