"""The ``sappc`` command line.

    sappc simulate SCENARIO.yaml [--controller sappc|trappc|blfppc] [--json FILE] [--plots DIR]

Errors in the input (bad scenario, infeasible parameters, bad values) print
one line naming the problem and exit with status 2; no traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from collections.abc import Sequence

from spacecraft_sim.core.validation import ConfigError, InputError

from .scenario import ControllerKind, load_scenario

__all__ = ["main"]

#: Exit status for invalid input (argparse uses the same).
EXIT_INVALID_INPUT = 2


def _format_value(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return "-" if value is None else str(value)


def _print_metrics(scenario_name: str, controller: str, metrics: dict[str, object]) -> None:
    print(f"scenario {scenario_name}, controller {controller}")
    width = max(len(k) for k in metrics)
    for key, value in metrics.items():
        print(f"  {key:<{width}}  {_format_value(value)}")


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .simulate import simulate

    scenario = load_scenario(args.scenario)
    result = simulate(scenario, args.controller)
    _print_metrics(scenario.name, result.controller.value, result.metrics)
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result.report(), indent=2) + "\n")
        print(f"wrote {path}")
    if args.plots:
        from .plots import plot_run

        for p in plot_run(result.history, Path(args.plots), title=f"{scenario.name} ({result.controller.value})",
                          fault_windows=scenario.disturbance.events()):
            print(f"wrote {p}")
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sappc", description="SAPPC spacecraft attitude control: offline runs and tools.")
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser("simulate", help="run a scenario offline (no ROS) and print its metrics")
    sim.add_argument("scenario", help="scenario YAML file, e.g. config/scenarios/paper_tracking.yaml")
    sim.add_argument("--controller", choices=[c.value for c in ControllerKind], default=None,
                     help="controller to run (default: the scenario's 'controller' key)")
    sim.add_argument("--json", metavar="FILE", help="write metrics and all parameters used as JSON")
    sim.add_argument("--plots", metavar="DIR", help="write paper-style PNG figures to DIR")
    sim.set_defaults(func=_cmd_simulate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sappc`` command."""
    args = _parser().parse_args(argv)
    try:
        return int(args.func(args))
    except (ConfigError, InputError) as exc:
        print(f"sappc: error: {exc}", file=sys.stderr)
        return EXIT_INVALID_INPUT


if __name__ == "__main__":
    sys.exit(main())
