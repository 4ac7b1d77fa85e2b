"""MkDocs hook: the reference pages, generated from the code each time the site is built.

A page asks for a generated part with a marker line of its own::

    <!-- generate: cli -->            every `sappc` command, from its argparse parser
    <!-- generate: nodes -->          every node's parameters, from the records it declares them from
    <!-- generate: scenario -->       every scenario key, from the dataclasses that validate it
    <!-- generate: topics -->         the topic contract, from :mod:`sappc_msgs_py.contract`
    <!-- generate: api PACKAGE -->    one mkdocstrings ``:::`` block per module of ``src/PACKAGE``
    <!-- generate: fault-matrix -->   benchmarks/results_fault_matrix.json, tabulated by its benchmark

The text comes from the objects the programs themselves use (the parser ``sappc`` parses with,
the ``Param`` records a node declares, the dataclass fields ``from_mapping`` accepts, the
contract's ``Topic`` records), so a reference page cannot drift from the code: a new option,
parameter, key or topic appears at the next build, and one the generators cannot describe
(an unknown marker, a scenario section or a topic without a description) stops the build.

The generators are plain functions returning Markdown; ``tests/test_docs.py`` calls them too.
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import importlib
import inspect
import re
import types
import typing
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src"

#: A marker line: ``<!-- generate: NAME [ARGUMENT] -->``.
MARKER = re.compile(r"^<!-- generate: ([\w-]+)(?: (\S+))? -->$", re.M)


class GenerationError(RuntimeError):
    """A reference page could not be generated from the code (the build stops)."""


# ---------------------------------------------------------------------------------------------
# text helpers


def md(text: object) -> str:
    """``text`` safe inside a Markdown table cell: reStructuredText roles and literals as code,
    ``|`` escaped, ``<`` and ``>`` outside code as entities, one line."""
    s = " ".join(str(text).split())
    s = re.sub(r":\w+:`~?\.?([^`]+)`", r"``\1``", s)  # :class:`~a.B` -> ``a.B``
    parts = re.split(r"(``[^`]*``)", s)
    out = []
    for part in parts:
        if part.startswith("``") and part.endswith("``") and len(part) > 4:
            out.append("`" + part[2:-2].replace("|", "\\|") + "`")
        else:
            out.append(part.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;"))
    return "".join(out)


def code(value: object) -> str:
    """A value as inline code (``|`` escaped for tables)."""
    return "`" + str(value).replace("|", "\\|").replace("`", "'") + "`"


def _sentence(text: str) -> str:
    """``text`` with a capital first letter and a full stop (argparse help is written lower case)."""
    text = text.strip()
    if not text:
        return ""
    return text[0].upper() + text[1:] + ("" if text.endswith(".") else ".")


def first_paragraph(doc: str | None) -> str:
    return (inspect.cleandoc(doc or "").split("\n\n", 1)[0]).strip()


def table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> str:
    header = list(header)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# sappc: the command line


def _subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            out += [(name, helps.get(name, ""), sub) for name, sub in action.choices.items()]
    return out


def _argument_rows(parser: argparse.ArgumentParser) -> list[list[str]]:
    """One row per argument ``--help`` shows: its name and its meaning (the help, which states the
    default where there is one, its choices, whether required); an argument ``--help`` hides
    (``help=argparse.SUPPRESS``, e.g. a deprecated alias) is left out, and one without a help
    stops the build."""
    rows = []
    for a in parser._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) or a.help == argparse.SUPPRESS:
            continue
        if not a.help:
            raise GenerationError(f"{parser.prog}: argument {'/'.join(a.option_strings) or a.dest} has no help (its meaning on the page)")
        if a.option_strings:
            name = ", ".join(a.option_strings)
            if a.nargs != 0:
                name += " " + (a.metavar or a.dest.upper())
        else:
            name = a.metavar or a.dest
            if a.nargs in ("+", "*"):
                name += " ..."
        what = [_sentence(a.help)]
        if a.choices is not None:
            what.append("One of " + ", ".join(f"``{c}``" for c in a.choices) + ".")
        if a.required and a.option_strings:
            what.append("Required.")
        if not a.option_strings and a.nargs == "?":
            what.append("Optional.")
        rows.append([code(name), md(" ".join(what))])
    return rows


def gen_cli(_: str | None = None) -> str:
    """Every ``sappc`` command: its usage and arguments, from the parser ``sappc`` runs."""
    import sappc.cli as cli

    parser = cli._parser()
    doc = inspect.cleandoc(cli.__doc__ or "")
    prose = [p for p in doc.split("\n\n")[1:] if not p.startswith(" ")]  # after the title; not the synopsis
    out = [f"`sappc` {md(parser.description or '')}", ""]
    out += [md(p) + "\n" for p in prose]
    commands = _subcommands(parser)
    out.append(table(["command", "what it does"], [[f"[`sappc {n}`](#sappc-{n})", md(h)] for n, h, _ in commands]))
    out += ["", "`sappc --version` prints the installed version. Every command exits with 2 on invalid input (one line names "
            "it) and 130 on Ctrl-C; each command's own statuses are listed with it."]

    def usage_of(sub: argparse.ArgumentParser) -> str:
        usage = " ".join(sub.format_usage().split())
        return usage[len("usage: "):] if usage.startswith("usage: ") else usage

    for name, help_text, sub in commands:
        out += ["", f"## sappc {name}", "", md(_sentence(help_text)), "", "```text", usage_of(sub), "```", ""]
        if _argument_rows(sub):
            out.append(table(["argument", "meaning"], _argument_rows(sub)))
        for sub_name, sub_help, nested in _subcommands(sub):  # e.g. sappc scenarios copy
            out += ["", f"`sappc {name} {sub_name}`: {md(_sentence(sub_help))}", "", "```text", usage_of(nested), "```", ""]
            out.append(table(["argument", "meaning"], _argument_rows(nested)))
        out += ["", "Exit status:", ""]
        out.append(table(["status", "meaning"], [[code(c), md(_sentence(m))] for c, m in sorted(cli.EXIT_STATUSES[name])]))
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------------------------
# nodes: their declared parameters


def node_classes() -> list[type]:
    """Every node run with ``python -m``: the classes under ``src/`` that set ``COMMAND`` and
    declare their parameters (``parameter_sections``), in the order of their commands."""
    found: dict[str, type] = {}
    for path in sorted(SRC.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        if not re.search(r'^\s+COMMAND = "python -m ', text, re.M):
            continue
        module = ".".join(path.relative_to(SRC).with_suffix("").parts)
        mod = importlib.import_module(module)
        for obj in vars(mod).values():
            if inspect.isclass(obj) and obj.__module__ == module and getattr(obj, "COMMAND", "") and hasattr(obj, "parameter_sections"):
                found[obj.COMMAND] = obj
    if not found:
        raise GenerationError("no node found under src/ (a class with COMMAND and parameter_sections)")
    first = ["python -m sappc_controller", "python -m sappc_estimator", "python -m spacecraft_sim"]  # the flight loop first
    return [found[k] for k in sorted(found, key=lambda k: (first.index(k) if k in first else len(first), k))]


def _show(value: Any) -> str:
    from sappc_msgs_py.parameters import REQUIRED

    if value is REQUIRED:
        return "required"
    if isinstance(value, str):
        return code(repr(value))
    if isinstance(value, float):
        return code(f"{value:g}")
    if isinstance(value, (list, tuple)):
        return code("[" + ", ".join(f"{v:g}" if isinstance(v, float) else repr(v) for v in value) + "]")
    return code(value)


def gen_nodes(_: str | None = None) -> str:
    """Every node's parameters, from the ``Param`` records it declares them from (as ``--help``)."""
    out = []
    for cls in node_classes():
        module = importlib.import_module(cls.__module__)
        summary = first_paragraph(module.__doc__)
        out += [f"## {cls.COMMAND}", "", md(summary), "",
                f"`{cls.COMMAND} --help` prints the same list.", ""]
        for title, params in cls.parameter_sections():
            out += [f"### {md(title[0].upper() + title[1:])}", ""]
            rows = []
            for p in params:
                rule = []
                if p.range is not None:
                    rule.append(f"[{p.range[0]:g}, {p.range[1]:g}]")
                if p.check:
                    rule.append(p.check)
                if p.choices:
                    rule.append("one of " + ", ".join(p.choices))
                rows.append([code(p.name), p.type, md(p.unit), _show(p.default), md("; ".join(rule)),
                             "yes" if p.changeable else "", md(p.description)])
            out += [table(["parameter", "type", "unit", "default", "range / rule", "changeable at run time", "description"], rows), ""]
    return "\n".join(out)


# ---------------------------------------------------------------------------------------------
# scenario files


def _type_name(hint: Any) -> str:
    if hint is type(None):
        return "null"
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return " \\| ".join(f"`{m.value}`" for m in hint)
    if dataclasses.is_dataclass(hint):
        return "mapping"
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(h) for h in typing.get_args(hint))
    if origin in (tuple, list):
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_name(args[0])}"
        return f"list of {len(args)}" + (f" {_type_name(args[0])}" if len(set(args)) == 1 else "")
    if origin is dict:
        k, v = typing.get_args(hint)
        return f"mapping of {_type_name(k)} to {_type_name(v)}"
    if isinstance(hint, type):
        return {"float": "number", "int": "integer", "str": "string", "bool": "boolean"}.get(hint.__name__, hint.__name__)
    return str(hint).replace("typing.", "")


def _nested(hint: Any) -> list[type]:
    """The dataclasses a field's type holds (``X``, ``X | None``, ``dict[str, X]``)."""
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return [hint]
    return [c for h in typing.get_args(hint) for c in _nested(h)]


def _default(f: dataclasses.Field[Any]) -> str:
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "required"
    if dataclasses.is_dataclass(value):
        return "see below"
    if value is None:
        return "`null`"
    if isinstance(value, enum.Enum):
        return code(value.value)
    if isinstance(value, bool):
        return code(str(value).lower())
    if isinstance(value, (tuple, list, dict)) and not value:
        return code("[]" if not isinstance(value, dict) else "{}")
    if isinstance(value, float):
        return code(f"{value:g}")
    return code(value if not isinstance(value, tuple) else list(value))


def _field_docs(cls: type) -> dict[str, str]:
    from sappc_msgs_py.parameters import field_docs

    return field_docs(cls)


def _anchor(key: str) -> str:
    return "key-" + re.sub(r"[^A-Za-z0-9_]+", "-", key).strip("-")


def dataclass_sections(cls: type, key: str, skip: Iterable[str] = (), extra: Iterable[list[str]] = (),
                       level: int = 3, rendered: dict[type, str] | None = None) -> list[str]:
    """Tables for the mapping at ``key`` validated by dataclass ``cls``, then one per nested
    dataclass field (depth first); a dataclass met again links to its first table."""
    rendered = {} if rendered is None else rendered
    rendered.setdefault(cls, key)
    hints = typing.get_type_hints(cls)
    docs = _field_docs(cls)
    rows = list(extra)
    nested: list[tuple[str, type]] = []
    for f in dataclasses.fields(cls):
        if not f.init or f.name in skip:
            continue
        hint = hints[f.name]
        sub_key = f"{key}.{f.name}" + (".NAME" if typing.get_origin(hint) is dict else "")
        kind = _type_name(hint)
        for c in _nested(hint):
            target = rendered.get(c, sub_key)
            label = f"`{c.__name__}`" if target.startswith("type ") else "mapping"
            kind = kind.replace("mapping", f"[{label}](#{_anchor(target)})", 1)
            if c not in rendered:
                rendered[c] = sub_key
                nested.append((sub_key, c))
        rows.append([code(f.name), kind, _default(f), md(docs.get(f.name, ""))])
    summary = first_paragraph(cls.__doc__)
    title = key[len("type "):] if key.startswith("type ") else key
    out = [f"{'#' * level} `{title}` {{ #{_anchor(key)} }}", "", f"{md(summary)} (`{cls.__module__}.{cls.__qualname__}`)", "",
           table(["key", "type", "default", "meaning"], rows), ""]
    for sub_key, sub in nested:
        out += dataclass_sections(sub, sub_key, level=min(level + 1, 4), rendered=rendered)
    return out


def _kind_sections(kinds: dict[str, type], key: str) -> list[str]:
    out = [f"## `{key}` {{ #{_anchor(key)} }}", "", "A list; each entry has a `kind` and that kind's keys.", ""]
    for kind, cls in kinds.items():
        extra = [[code("kind"), "string", "required", f"`{kind}`"]]
        out += dataclass_sections(cls, f"{key}[kind: {kind}]", extra=extra, level=3)
    return out


#: What each top-level key of a scenario holds.  Every key the loader accepts must be here (the
#: build stops otherwise); the keys' contents are generated from the code below.
TOP_KEYS = {
    "name": "The scenario's name (run directories, figures, reports). Required.",
    "description": "Free text.",
    "duration_s": "Simulated duration [s]. Required.",
    "control_period_s": "Control period `dt` [s]: the controller's rate, the plant's zero-order hold. Required.",
    "plant": "The rigid body: `inertia_kg_m2` (3x3, symmetric positive definite, a physical rigid body) and "
             "`rk4_substeps` (RK4 steps per control period, default 1). Required.",
    "initial_state": "`q_BN` (x, y, z, w; normalised on loading) and `omega_BN_B_rad_s` (3). Required.",
    "reference": "The paper's desired trajectory.",
    "disturbances": "A list of external torques, each with a `kind`.",
    "actuator": "The controller's limits and the plant's actuator (`kind: ideal` or `reaction_wheels`).",
    "sensors": "The plant's star tracker and gyro; absent: the state is measured exactly.",
    "estimator": "Attitude determination between the sensors and the controller (`kind: none` or `mekf`).",
    "orbit": "The orbit, the Earth's magnetic field (a centred dipole) and the gravity-gradient torque; absent: "
             "no orbit (the paper's inertial setting).",
    "magnetorquers": "The torque rods (`m x B` on the body); needs `orbit`.",
    "magnetometer": "What the flight software reads the Earth's field with (noise, bias, rate); needs `orbit`; absent: "
                    "the true field, exactly.",
    "momentum_management": "The flight software's momentum dumping with the rods and the wheels' feed-forward; needs "
                           "`magnetorquers` and `actuator.kind: reaction_wheels`.",
    "modes": "The flight modes (DETUMBLE, HOLD, TRACK, SAFE: docs/design/modes.md); needs `magnetorquers` and "
             "`momentum_management`; absent: the controller flies from the first sample.",
    "metrics": "How the run's metrics are computed, and the requirements a run must meet.",
    "controller": "The default controller: `sappc`, `trappc`, `blfppc` or `mrp_feedback` (default `sappc`).",
    "controllers": "The parameters of each controller the scenario can run, by name. Required.",
    "faults": "A list of actuator, sensor and link faults, each with a `kind`.",
    "controller_node": "The controller's input watchdog (both the node and the offline loop model it).",
    "montecarlo": "A campaign (`sappc montecarlo`, `sappc tune`).",
    "tuning": "A gain study (`sappc tune`).",
}


def gen_scenario(_: str | None = None) -> str:
    """Every key of a scenario file, from the dataclasses and lists the loader validates it with."""
    import sappc.scenario as sc
    from sappc.montecarlo.config import CampaignConfig
    from sappc.montecarlo.tuning import TuningConfig
    from sappc_controller.core.common import ActuatorConfig
    from sappc_controller.params import CONFIG_CLASSES
    from sappc_estimator.core.config import MekfConfig
    from spacecraft_sim.core.disturbance import DISTURBANCE_KINDS
    from spacecraft_sim.core.faults import FAULT_KINDS
    from spacecraft_sim.core.reference import PaperReference
    from spacecraft_sim.core.sensors import Sensors
    from spacecraft_sim.core.wheels import ReactionWheels
    from spacecraft_sim.core.magnetic_field import DipoleField
    from spacecraft_sim.core.magnetorquers import Magnetorquers
    from spacecraft_sim.core.magnetometer import Magnetometer
    from spacecraft_sim.core.orbit import Orbit
    from sappc_momentum.core.law import MomentumManagement

    accepted = set(sc._TOP_KEYS)
    if accepted != set(TOP_KEYS):
        raise GenerationError(f"scenario keys without a description in docs/_hooks/reference.py: {sorted(accepted - set(TOP_KEYS))}; "
                              f"described but not accepted: {sorted(set(TOP_KEYS) - accepted)}")
    from sappc.montecarlo.config import Distribution

    shared: dict[type, str] = {Distribution: "type Distribution"}  # used by many keys: one table, linked
    rendered = dict(shared)
    out = ["## Top-level keys", "", table(["key", "meaning"], [[code(k), v] for k, v in TOP_KEYS.items()]), ""]
    out += dataclass_sections(PaperReference, "reference", level=2)
    out += _kind_sections(DISTURBANCE_KINDS, "disturbances")
    kinds = " or ".join(f"`{k}`" for k in sc.ACTUATOR_KINDS)
    out += dataclass_sections(ActuatorConfig, "actuator", level=2, extra=[
        [code("kind"), kinds, code(sc.ACTUATOR_KINDS[0]), "The plant's actuator: the commanded torque exactly, or reaction wheels."],
        [code("wheels"), f"[mapping](#{_anchor('actuator.wheels')})", "", "With `kind: reaction_wheels` only: the wheel set."]])
    out += dataclass_sections(ReactionWheels, "actuator.wheels", level=3)
    out += dataclass_sections(Sensors, "sensors", level=2)
    est_kinds = " or ".join(f"`{k}`" for k in sc.ESTIMATOR_KINDS)
    out += dataclass_sections(MekfConfig, "estimator", level=2, extra=[
        [code("kind"), est_kinds, code(sc.ESTIMATOR_KINDS[0]), "The filter; the other keys are for `kind: mekf` only, "
         "and its noise figures default to the `sensors` section's."]])
    out += dataclass_sections(Orbit, "orbit", level=2, extra=[
        [code("magnetic_field"), f"[mapping](#{_anchor('orbit.magnetic_field')})", "see below", "The Earth's field: a centred dipole."],
        [code("gravity_gradient"), "boolean", code("false"), "Whether the gravity-gradient torque acts on the spacecraft."]])
    out += dataclass_sections(DipoleField, "orbit.magnetic_field", level=3)
    out += dataclass_sections(Magnetorquers, "magnetorquers", level=2)
    out += dataclass_sections(Magnetometer, "magnetometer", level=2)
    out += dataclass_sections(MomentumManagement, "momentum_management", level=2)
    from sappc_controller.core.mrp_feedback import MrpFeedbackGains
    from sappc_modes.core.modes import MODE_NAMES, ModeConfig

    out += ["## `modes` { #key-modes }", "", table(["key", "type", "default", "meaning"], [
        [code("initial_mode"), " or ".join(code(m) for m in MODE_NAMES), code(MODE_NAMES[0]), "The first mode (a flight after separation: DETUMBLE)."],
        [code("detumble_gain_N_m_s"), f"number or {code(sc.GAIN_CRITERION)}", code(sc.GAIN_CRITERION),
         "B-dot's gain [N m s]; `criterion`: `k* = 2 n (1 + sin xi_m) J_min` from the orbit, the field and the inertia."],
        [code("hold_gains"), f"[mapping](#{_anchor('modes.hold_gains')})", "required", "HOLD's MRP feedback gains (SAFE: `P_Nms` alone)."],
        [code("hold_attitude"), " or ".join(code(a) for a in sc.HOLD_ATTITUDES), code(sc.HOLD_ATTITUDES[0]),
         "HOLD holds the attitude of its entry, or points at the scenario's reference (an acquisition before TRACK)."],
        [code("requests"), "list of `{at_s, mode}`", "none",
         "The ground's mode requests, each at the first sample at or after `at_s` [s], at once from any mode."],
        [code("transitions"), f"[mapping](#{_anchor('modes.transitions')})", "see below", "The guards' thresholds and persistences."]]), ""]
    out += dataclass_sections(MrpFeedbackGains, "modes.hold_gains", level=3)
    out += dataclass_sections(ModeConfig, "modes.transitions", level=3)
    out += dataclass_sections(sc.MetricSettings, "metrics", level=2)
    out += ["Requirements (`metrics.requirements`) bound a metric from above: "
            + ", ".join(f"`{m}_max`" for m in sc.BOUNDED_METRICS) + ".", ""]
    out += dataclass_sections(sc.ControllerNodeSettings, "controller_node", level=2)
    out += ["## `controllers` { #key-controllers }", "",
            "One mapping per controller; `inertia_kg_m2` and `actuator` come from the scenario's `plant` and "
            "`actuator` sections, not from here.", ""]
    for kind, cls in CONFIG_CLASSES.items():
        out += dataclass_sections(cls, f"controllers.{kind}", skip=("inertia_kg_m2", "actuator"), level=3)
    out += _kind_sections(FAULT_KINDS, "faults")
    out += ["Windows are `[start_s, end_s)` on the sample stamps; `end_s: null` lasts to the end.", ""]
    out += dataclass_sections(CampaignConfig, "montecarlo", level=2, rendered=rendered)
    out += dataclass_sections(TuningConfig, "tuning", level=2, rendered=rendered)
    out += ["## Shared mappings", ""]
    for cls, key in shared.items():
        out += dataclass_sections(cls, key, level=3, rendered={})
    return "\n".join(out)


# ---------------------------------------------------------------------------------------------
# the topic contract


_CONTRACT_ROW = re.compile(r"^``(\S+)``\s+(\S+)\s+(?:``\w+``|\(none\))\s+(.+)$")


def gen_topics(_: str | None = None) -> str:
    """The topic contract: every topic with its type, frames and content, the QoS, the relayed
    topics, the diagnostics rows and the answer codes (:mod:`sappc_msgs_py.contract`)."""
    import sappc_msgs_py.contract as c

    content = {}
    for line in inspect.cleandoc(c.__doc__ or "").splitlines():
        m = _CONTRACT_ROW.match(line.strip())
        if m:
            content[m.group(1)] = m.group(3).strip()
    rows = []
    for t in c.TOPICS:
        if t.name not in content:
            raise GenerationError(f"topic {t.name} has no row in the table of sappc_msgs_py.contract's docstring")
        notes = []
        if t in c.OPTIONAL_TOPICS:
            notes.append("only some plants")
        if t in c.RELAYED_TOPICS:
            notes.append(f"relayed as `{c.faulty(t).name}`")
        if t in c.CONTROLLER_INPUTS:
            notes.append("controller input")
        rows.append([code(t.name), code(t.type_name), code(t.frame_id) if t.frame_id else "-",
                     code(t.child_frame_id) if t.child_frame_id else "", md(content[t.name]), "; ".join(notes)])
    out = [table(["topic", "type", "frame_id", "child_frame_id", "content", "notes"], rows), "",
           f"**QoS** of every topic: RELIABLE, VOLATILE, KEEP_LAST, depth {c.QOS_DEPTH:,} "
           f"(`sappc_msgs_py.contract.qos_profile()`).", ""]
    src = inspect.getsource(c)
    block = src.split("DIAGNOSTICS_LAYOUT = (", 1)[1].split("\n)", 1)[0]
    comments = dict(re.findall(r'"(\w+)",\s*#\s*(.*)', block))
    out += ["## `controller/diagnostics`", "",
            "`std_msgs/Float64MultiArray`, labelled rows of 3 values each (`layout.dim[0].label`), in this order; "
            "row `i` is `data[3 i : 3 i + 3]`.", "",
            table(["row", "label", "content"], [[str(i), code(r), md(comments.get(r, ""))] for i, r in enumerate(c.DIAGNOSTICS_LAYOUT)]), "",
            "The answer codes of `status[2]` (and of the offline loop's record): "
            + ", ".join(f"{i} `{n}`" for i, n in enumerate(c.ANSWER_NAMES)) + ".", ""]
    return "\n".join(out)


# ---------------------------------------------------------------------------------------------
# the Python API


def modules_of(package: str) -> list[str]:
    """Every module of ``src/<package>``, package first, without ``__main__`` and private modules."""
    base = SRC / package
    if not (base / "__init__.py").exists():
        raise GenerationError(f"no package src/{package}")
    mods = []
    for path in sorted(base.rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if parts[-1] == "__main__" or any(p.startswith("_") for p in parts):
            continue
        mods.append(".".join(parts))
    return sorted(mods)


def gen_api(package: str | None) -> str:
    """One mkdocstrings block per module of ``package`` (a new module appears by itself)."""
    if not package:
        raise GenerationError("<!-- generate: api PACKAGE --> needs the package")
    return "\n".join(f"::: {m}\n" for m in modules_of(package))


def gen_fault_matrix(_: str | None = None) -> str:
    """The fault matrix as recorded in ``benchmarks/results_fault_matrix.json``, tabulated by the
    benchmark's own ``--table`` (``python benchmarks/bench_fault_matrix.py --table FILE``)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_fault_matrix", ROOT / "benchmarks" / "bench_fault_matrix.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return str(bench.table(str(ROOT / "benchmarks" / "results_fault_matrix.json"))) + "\n"


GENERATORS: dict[str, Callable[[str | None], str]] = {
    "fault-matrix": gen_fault_matrix,
    "cli": gen_cli,
    "nodes": gen_nodes,
    "scenario": gen_scenario,
    "topics": gen_topics,
    "api": gen_api,
}


def expand(markdown: str) -> str:
    """Replace every marker in ``markdown`` by its generated text."""

    def one(m: re.Match[str]) -> str:
        if m.group(1) not in GENERATORS:
            raise GenerationError(f"unknown generator {m.group(1)!r} (known: {', '.join(GENERATORS)})")
        return GENERATORS[m.group(1)](m.group(2))

    return MARKER.sub(one, markdown)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:  # MkDocs hook
    return expand(markdown)
