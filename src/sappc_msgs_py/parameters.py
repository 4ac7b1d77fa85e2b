"""The declared parameters of the project's nodes, and the ``--help`` made from them.

Each node lists its parameters as :class:`Param` records (name, type, unit, range, default,
description); the node declares them from that list (:meth:`sappc_msgs_py.runtime.ProjectNode.param`:
the descriptor rclpy enforces and ``ros2 param describe`` shows is built from the record), and
``python -m <node> --help`` prints the same list (:func:`format_help`), so the help cannot drift
from what the node declares (a test compares the two for every node).

No rclpy at import: ``--help`` answers before ROS is initialised.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["Param", "REQUIRED", "descriptor", "field_docs", "format_help", "plain", "ros_type", "unit_of"]


class _Required:
    """The default of a parameter that has none (the node stops with an error naming it when unset)."""

    def __repr__(self) -> str:
        return "(required)"


#: The default of a parameter without one.
REQUIRED: Any = _Required()


@dataclass(frozen=True)
class Param:
    """One declared parameter of a node.

    Attributes
    ----------
    name : str
        The ROS parameter name (dotted for nested ones, e.g. ``sappc.gains.K_q``).
    default : Any
        The value when the parameter is not given, or :data:`REQUIRED`.
    description : str
        What it does, one sentence or two.
    unit : str
        Its unit (``s``, ``N m``, ``rad/s``, ``kg m^2``...), ``""`` when dimensionless or not a quantity.
    range : tuple or None
        Inclusive ``(low, high)`` of a scalar, enforced by rclpy through the descriptor.
    check : str
        The rule the node checks at start-up with its own words (``> 0``, ``a positive
        integer``...), for a parameter whose rule a range cannot say.
    choices : tuple of str or None
        The allowed values of a string parameter (checked by the node).
    type : str
        The ROS type (``double``, ``integer``, ``bool``, ``string``, ``double[]``, ``string[]``);
        derived from the default when empty.
    read_only : bool
        Read once at start-up (a change at run time is refused by rclpy with the reason).
    dynamic_typing : bool
        Accept any type (an integer for a double: ``K_q: 1`` in a YAML file); the node converts.
    changeable : bool
        Whether the node applies a change at run time (``--help`` says so); by default, when it is
        not read-only.  A parameter may be writable yet refused by the node's own callback with
        its reason (the controller's fixed gains).
    """

    name: str
    default: Any
    description: str
    unit: str = ""
    range: tuple[float, float] | tuple[int, int] | None = None
    check: str = ""
    choices: tuple[str, ...] | None = None
    type: str = ""
    read_only: bool = True
    dynamic_typing: bool = False
    changeable: bool | None = None

    def __post_init__(self) -> None:
        if not self.type:
            object.__setattr__(self, "type", ros_type(self.default))
        if self.changeable is None:
            object.__setattr__(self, "changeable", not self.read_only)

    @property
    def required(self) -> bool:
        return self.default is REQUIRED


def ros_type(default: Any) -> str:
    """The ROS parameter type of a default value (raises ``ValueError`` for :data:`REQUIRED` or an empty list)."""
    if isinstance(default, bool):
        return "bool"
    if isinstance(default, int):
        return "integer"
    if isinstance(default, float):
        return "double"
    if isinstance(default, str):
        return "string"
    if isinstance(default, (list, tuple)) and default:
        return ros_type(default[0]) + "[]"
    raise ValueError(f"the type of default {default!r} cannot be derived: give Param.type")


def descriptor(p: Param) -> Any:
    """The ``rcl_interfaces/ParameterDescriptor`` of ``p`` (description with unit, range, read-only)."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    text = f"[{p.unit}] {plain(p.description)}" if p.unit else plain(p.description)
    if p.choices:
        text += f" (one of {', '.join(p.choices)})"
    if p.check:
        text += f" (must be {p.check})"
    d = ParameterDescriptor(description=text, read_only=p.read_only, dynamic_typing=p.dynamic_typing)
    if p.range is not None and p.type == "integer":
        d.integer_range = [IntegerRange(from_value=int(p.range[0]), to_value=int(p.range[1]), step=1)]
    elif p.range is not None and p.type == "double":
        d.floating_point_range = [FloatingPointRange(from_value=float(p.range[0]), to_value=float(p.range[1]), step=0.0)]
    return d


def _show(value: Any) -> str:
    if value is REQUIRED:
        return "(required)"
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)


def plain(text: str) -> str:
    """reStructuredText markup (````code````, ``:class:`~x.y```) as plain text, for a terminal."""
    return re.sub(r":\w+:`~?\.?([^`]+)`", r"\1", text).replace("``", "")


def format_help(command: str, summary: str, sections: Sequence[tuple[str, Iterable[Param]]]) -> str:
    """The ``--help`` text of a node: how to run it, then each section's parameters with type,
    unit, default, range and description."""
    out = [f"usage: {command} [--help] [--ros-args -p NAME:=VALUE ... --params-file FILE ...]", "", plain(summary), ""]
    for title, params in sections:
        out.append(f"{title}:")
        for p in params:
            facts = [p.type, *([f"[{p.unit}]"] if p.unit else []), f"default {_show(p.default)}"]
            if p.range is not None:
                facts.append(f"range [{_show(p.range[0])}, {_show(p.range[1])}]")
            if p.check:
                facts.append(f"must be {p.check}")
            if p.choices:
                facts.append(f"one of {', '.join(p.choices)}")
            if p.changeable:
                facts.append("changeable at run time")
            out.append(f"  {p.name}  ({'; '.join(facts)})")
            out.append(f"      {plain(p.description)}")
        out.append("")
    out.append("Parameters are ROS parameters: -p NAME:=VALUE after --ros-args, or a YAML file with --params-file.")
    return "\n".join(out)


#: Units named by a parameter's suffix (the project's naming rule: names carry units), longest first.
_SUFFIX_UNITS = (("_kg_m2", "kg m^2"), ("_rad_s", "rad/s"), ("_deg_s", "deg/s"), ("_Nm", "N m"), ("_deg", "deg"), ("_s", "s"))


def unit_of(name: str, description: str = "") -> str:
    """A parameter's unit: a trailing ``[unit]`` of its description, else its name's suffix, else ``""``."""
    m = re.search(r"\[([^\]]+)\]\.?\s*$", description)
    if m:
        return m.group(1)
    leaf = name.rsplit(".", 1)[-1]
    return next((unit for suffix, unit in _SUFFIX_UNITS if leaf.endswith(suffix)), "")


def field_docs(cls: type) -> dict[str, str]:
    """The description of each field in the numpy-style ``Attributes`` section of a dataclass's
    docstring (``name : type`` lines, ``a, b : type`` for several, the indented text below)."""
    doc = cls.__doc__ or ""
    lines = doc.splitlines()
    out: dict[str, str] = {}
    try:
        start = next(i for i, ln in enumerate(lines) if ln.strip() == "Attributes") + 2
    except StopIteration:
        return out
    names: list[str] = []
    fields = {f.name for f in dataclasses.fields(cls)}
    for ln in lines[start:]:
        head = re.match(r"^\s{4}([A-Za-z_][\w, ]*?)\s:\s?(.*)$", ln)
        if head and all(n.strip() in fields for n in head.group(1).split(",")):
            names = [n.strip() for n in head.group(1).split(",")]
            for n in names:
                out[n] = ""
        elif ln.strip() and names:
            for n in names:
                out[n] = (out[n] + " " + ln.strip()).strip()
        elif not ln.strip() and names:
            names = []  # a blank line ends the entry
    return out
