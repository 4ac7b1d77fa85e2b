"""``ros2msg`` schema texts and RIHS01 type hashes, as a recorder writes them into MCAP.

With ROS 2 from PyPI wheels ``AMENT_PREFIX_PATH`` is unset; the interface files live under
``sys.prefix/share/<pkg>/msg/``: ``<Type>.msg`` (the definition) and ``<Type>.json`` (whose
``type_hashes`` list holds the RIHS01 hash of the type and of each dependency).

Schema text (what rosbag2 writes): the type's ``.msg`` text, then for each dependency, sorted by
name and found recursively, a line of 80 ``=``, a line ``MSG: pkg/Type`` and that type's text.
"""

from __future__ import annotations

import json
import re
import sys
from functools import cache
from pathlib import Path

__all__ = ["dependencies", "schema_text", "type_hash"]

#: Field types that are not messages.
_PRIMITIVES = {
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
}
_SEPARATOR = "=" * 80


def _split(type_name: str) -> tuple[str, str]:
    """``pkg/msg/Type`` or ``pkg/Type`` -> (pkg, Type)."""
    parts = type_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError(f"not a message type name: {type_name!r} (expected 'pkg/msg/Type')")


def _share() -> Path:
    return Path(sys.prefix) / "share"


@cache
def _msg_text(pkg: str, name: str) -> str:
    path = _share() / pkg / "msg" / f"{name}.msg"
    try:
        return path.read_text()
    except OSError:
        raise FileNotFoundError(f"no interface definition {path}: is the ROS 2 package {pkg!r} installed?") from None


def _field_types(pkg: str, name: str) -> list[str]:
    """Message types used by the fields of ``pkg/Type`` (as ``pkg/Type``)."""
    found = []
    for raw in _msg_text(pkg, name).splitlines():
        tokens = raw.split("#", 1)[0].split()
        if len(tokens) < 2 or "=" in tokens[1]:
            continue  # blank, comment, or a constant ('type NAME=value')
        base = re.sub(r"\[.*\]$", "", tokens[0]).split("<=")[0]  # drop array and bound suffixes
        if base not in _PRIMITIVES:
            found.append(base if "/" in base else f"{pkg}/{base}")
    return found


def dependencies(type_name: str) -> list[str]:
    """Every message type ``type_name`` depends on, recursively, sorted (``pkg/Type``)."""
    pkg, name = _split(type_name)
    seen: set[str] = set()
    todo = _field_types(pkg, name)
    while todo:
        dep = todo.pop()
        if dep not in seen:
            seen.add(dep)
            todo.extend(_field_types(*_split(dep)))
    return sorted(seen)


def schema_text(type_name: str) -> str:
    """The ``ros2msg`` schema text of ``type_name`` with its dependencies."""
    pkg, name = _split(type_name)
    parts = [_msg_text(pkg, name)]
    for dep in dependencies(type_name):
        parts.append(f"{_SEPARATOR}\nMSG: {dep}\n{_msg_text(*_split(dep))}")
    return "\n".join(p.rstrip("\n") for p in parts) + "\n"


def type_hash(type_name: str) -> str:
    """The RIHS01 hash of ``type_name`` (``pkg/msg/Type``)."""
    pkg, name = _split(type_name)
    path = _share() / pkg / "msg" / f"{name}.json"
    data = json.loads(path.read_text())
    full = f"{pkg}/msg/{name}"
    for entry in data["type_hashes"]:
        if entry["type_name"] == full:
            return str(entry["hash_string"])
    raise KeyError(f"{path} lists no hash for {full}")
