"""Boundary checks shared by every core: finite numbers, unit quaternions, SPD inertia.

Inputs are converted and checked once, where they enter a core object; the
numerical kernels behind that boundary assume clean float64 arrays.  Every
error names the offending quantity and value.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from enum import Enum
from pathlib import Path
from typing import Any

import math
import os

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "ConfigError",
    "INERTIA_TRIANGLE_RTOL",
    "INITIAL_QUATERNION_NORM_TOL",
    "InputError",
    "MAX_MESSAGE_CHARS",
    "MAX_QUOTED_CHARS",
    "MAX_YAML_BYTES",
    "MAX_YAML_DEPTH",
    "MAX_YAML_NODES",
    "QUATERNION_NORM_TOL",
    "YAML_REPARSE_BYTES",
    "as_finite_array",
    "check_initial_quaternion",
    "check_positive",
    "check_positive_int",
    "check_spd_inertia",
    "check_unit_quaternion",
    "did_you_mean",
    "from_kind_list",
    "inertia_from_row_major",
    "from_mapping",
    "holds_bool",
    "quoted",
    "read_text_file",
    "read_yaml_file",
    "safe_load_yaml",
]

#: Largest accepted | ||q|| - 1 | for a quaternion given as input.  Measured
#: attitudes from a plant are normalised to float64 precision (1e-15); 1e-6 also
#: admits attitudes printed with 7 significant digits, yet rejects any quaternion
#: that was never normalised (e.g. the paper's q_s(0) as printed has a norm error
#: of 3e-5 and is normalised explicitly by the scenario loader instead).
QUATERNION_NORM_TOL = 1e-6
#: Largest norm error accepted (and corrected) in an initial quaternion typed by hand (a scenario
#: file, a plant node parameter): the paper prints q_s(0) with 4 decimals (norm error 3.5e-5);
#: anything beyond 1e-3 is a typo, not rounding.
INITIAL_QUATERNION_NORM_TOL = 1e-3


#: How close a mistyped name must be to a valid one for :func:`did_you_mean` to suggest it
#: (``difflib.SequenceMatcher.ratio``, 0 to 1): difflib's own default, 0.6, which takes
#: ``simulat`` to ``simulate`` and ``paper-tracking`` or ``paper_trackin`` to ``paper_tracking``
#: (ratios above 0.9) and suggests nothing for a word that shares a few letters by chance.
SUGGESTION_CUTOFF = 0.6


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """``", did you mean 'X'?"`` naming the valid choice closest to a mistyped ``word``, to put
    into an error message right after the word; ``""`` when no choice is close
    (:data:`SUGGESTION_CUTOFF`).

    >>> did_you_mean("simulat", ["simulate", "montecarlo"])
    ", did you mean 'simulate'?"
    """
    import difflib

    close = difflib.get_close_matches(word, [str(c) for c in choices], n=1, cutoff=SUGGESTION_CUTOFF)
    return f", did you mean {close[0]!r}?" if close else ""


class InputError(ValueError):
    """A numeric input (state, reference, step) is non-finite or malformed."""

    #: The rejection reason a node counts it under (:data:`sappc_msgs_py.inputs.REJECT_REASONS`).
    reason = "invalid"


class ConfigError(ValueError):
    """A configuration value is missing, unknown, out of range or inconsistent.

    Its message is one line (the command line prints it as ``sappc: error: <message>`` and exits 2)
    of at most :data:`MAX_MESSAGE_CHARS` characters: a longer one keeps its start and its end.
    """

    def __init__(self, *args: object) -> None:
        if len(args) == 1 and isinstance(args[0], str):
            args = (_one_line(args[0]),)
        super().__init__(*args)


#: The longest YAML text read [characters; a file's bytes are at least as many], 4 MiB, the bound
#: of a scenario file (:data:`sappc.scenario.MAX_SCENARIO_BYTES`: the largest bundled scenario is
#: under 11 kB, a YAML parser takes about sixty times a text's size in memory), for every text the
#: loader parses: a parameters file, a fault schedule, what a bag records.
MAX_YAML_BYTES = 4 << 20
#: The deepest nesting of mappings and sequences in a YAML text, aliases expanded: the files sappc
#: reads nest 8 deep at most (a bag's rosbag2 ``metadata.yaml``; the bundled scenarios and the ROS
#: parameters files 5).  Everything that reads a parsed
#: tree walks it by recursion (the libyaml composer in C, the validation helpers, ``repr`` in a
#: message) with one to three frames a level: at 32 levels a walk stays far from Python's
#: recursion limit (1000 frames), where 1,000 levels raised ``RecursionError`` and 30,000 overflowed
#: the C stack (a segmentation fault, issue 46).
MAX_YAML_DEPTH = 32
#: The most nodes (scalars, mappings, sequences) of a YAML text, each alias counted as the whole
#: node it names: the files sappc reads hold 500 at most (a bag's ``metadata.yaml`` of 11 topics;
#: the bundled scenarios 300).  An alias costs the loader nothing
#: (the value is shared), but every walk of the value (the checks, a message quoting it) meets
#: it in full, so ten aliases per level nested six levels deep (a few hundred bytes) reach a
#: million nodes: 7 s and a 36 MB message (issue 46).  100,000 keeps a walk under a tenth of a
#: second.
MAX_YAML_NODES = 100_000
#: The longest YAML text that PyYAML's pure-Python parser parses again when libyaml's refuses it
#: [characters], for PyYAML's message (it names the character or the alias at fault, where
#: libyaml's does not): that parser reads about 1.2 MB/s (3.5 s for a text at
#: :data:`MAX_YAML_BYTES`), so 256 kiB, twenty times the largest bundled scenario, keeps an error
#: under a quarter of a second; a larger text gets libyaml's message.
YAML_REPARSE_BYTES = 256 << 10
#: The longest quotation of a value in an error message [characters] (:func:`quoted`): enough to
#: recognise a short list or a 3x3 matrix, never a whole value read from a file.
MAX_QUOTED_CHARS = 100
#: The longest :class:`ConfigError` message [characters]; a longer one keeps its start and end and
#: says how much was cut.  The messages the code composes itself stay under it (the longest, about
#: 600 characters, lists the bundled scenarios); only a value quoted in full would exceed it.
MAX_MESSAGE_CHARS = 1000


def quoted(value: Any, limit: int = MAX_QUOTED_CHARS) -> str:
    """``repr(value)`` for an error message, at most ``limit`` characters: a long string, list or
    mapping is abridged (``reprlib``: a few items of each container, three levels) and what is left
    beyond ``limit`` cut with ``...``, so that a message never repeats a large value read from a file.

    >>> quoted([0.0, 0.0, 1.0])
    '[0.0, 0.0, 1.0]'
    >>> quoted(list(range(1000)))
    '[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, ...]'
    """
    import reprlib

    r = reprlib.Repr()
    r.maxlevel = 3
    r.maxlist = r.maxtuple = r.maxset = r.maxfrozenset = r.maxdeque = r.maxarray = 12
    r.maxdict = 6
    r.maxstring = r.maxother = r.maxlong = limit
    text = " ".join(r.repr(value).split("\n"))
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _one_line(message: str) -> str:
    """``message`` on one line and at most :data:`MAX_MESSAGE_CHARS` long (its middle cut)."""
    if "\n" in message or "\r" in message:
        message = " ".join(message.splitlines())
    if len(message) <= MAX_MESSAGE_CHARS:
        return message
    keep = MAX_MESSAGE_CHARS - 40
    cut = len(message) - keep
    return f"{message[: keep // 2]} ... [{cut:,} characters cut] ... {message[len(message) - keep // 2:]}"


def safe_load_yaml(text: str, *, source: str = "YAML text") -> Any:
    """The value of a YAML text, as ``yaml.safe_load(text)`` gives it, once the text is known to be
    small enough to build and walk: at most :data:`MAX_YAML_BYTES` characters, nested at most
    :data:`MAX_YAML_DEPTH` deep and of at most :data:`MAX_YAML_NODES` nodes, aliases expanded (an
    alias inside the node it names, a recursive value, is refused too).

    The limits are checked on the parser's events, before any value is built: the parser keeps its
    own stacks (no recursion), stops at the first event past a limit, and keeps no event, so a
    refused text costs its parse up to that point and no more (5 ms at most for the files of issue
    46: docs/performance.md).  The text is then parsed again by libyaml's loader (``CSafeLoader``, about ten times faster
    than PyYAML's own; the same constructor and resolver, so the same values); on a YAML error a
    text of at most :data:`YAML_REPARSE_BYTES` is parsed again by the pure-Python loader (under the
    same limits), so that a text either accepts is read, and the error is PyYAML's, with its words.

    Parameters
    ----------
    text : str
        The YAML text.
    source : str
        What it is, for the messages: a file's path, a bag's record.

    Returns
    -------
    Any
        The value: what ``yaml.safe_load`` returns (``None`` for an empty text).

    Raises
    ------
    ConfigError
        One line, naming ``source``: the text is not YAML (the problem, its line and column), or
        it exceeds a limit (naming the limit, and where the parser was).
    """
    import yaml

    if len(text) > MAX_YAML_BYTES:
        raise ConfigError(f"{source}: a YAML text of {len(text):,} characters, more than the {MAX_YAML_BYTES:,} read "
                          "(gnc_common.validation.MAX_YAML_BYTES): is it the right file?")
    fast = getattr(yaml, "CSafeLoader", None)
    try:
        if fast is not None:
            try:
                _check_yaml_events(text, source, fast)
                return yaml.load(text, Loader=fast)  # noqa: S506  (a safe loader)
            except yaml.YAMLError:
                if len(text) > YAML_REPARSE_BYTES:
                    raise
        _check_yaml_events(text, source, yaml.SafeLoader)
        return yaml.load(text, Loader=yaml.SafeLoader)  # noqa: S506  (a safe loader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source} is not valid YAML: {_yaml_problem(exc)}") from None


def _check_yaml_events(text: str, source: str, loader: type) -> None:
    """Refuse ``text`` (:class:`ConfigError`) at the first parser event past :data:`MAX_YAML_DEPTH`
    or :data:`MAX_YAML_NODES`, aliases expanded, or at an alias to a node that holds it; a YAML error
    is raised as the parser raises it.

    Each anchored node's size (its nodes, aliases expanded) and height (the levels it nests) is
    kept, so that an alias counts as the node it names, and nests as deep as it does, where it is
    used: the expanded counts grow by one addition per event, whatever the text's shape.
    """
    import yaml
    from yaml.events import (AliasEvent, DocumentStartEvent, MappingEndEvent, MappingStartEvent, ScalarEvent,
                             SequenceEndEvent, SequenceStartEvent)

    starts, ends = (MappingStartEvent, SequenceStartEvent), (MappingEndEvent, SequenceEndEvent)
    anchors: dict[str, tuple[int, int] | None] = {}  # size and height of each anchored node; None while it is open
    open_nodes: list[list[Any]] = []  # per open collection: [anchor, nodes counted before it, height of its tallest child]
    nodes = 0

    def where(event: Any) -> str:
        mark = event.start_mark
        return f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "its end"

    events: Iterator[Any] = yaml.parse(text, Loader=loader)  # (the stubs type them Event, without anchors)
    for event in events:
        kind = type(event)
        if kind is ScalarEvent:
            nodes += 1
            if event.anchor is not None:
                anchors[event.anchor] = (1, 0)
        elif kind in starts:
            nodes += 1
            if len(open_nodes) >= MAX_YAML_DEPTH:
                raise ConfigError(f"{source}: YAML nested more than {MAX_YAML_DEPTH} levels deep at {where(event)} (limit "
                                  "gnc_common.validation.MAX_YAML_DEPTH; sappc's own files nest 8 deep)")
            if event.anchor is not None:
                anchors[event.anchor] = None
            open_nodes.append([event.anchor, nodes - 1, 0])
        elif kind in ends:
            anchor, before, tallest = open_nodes.pop()
            height = tallest + 1
            if anchor is not None:
                anchors[anchor] = (nodes - before, height)
            if open_nodes:
                open_nodes[-1][2] = max(open_nodes[-1][2], height)
        elif kind is AliasEvent:
            named = anchors.get(event.anchor, (1, 0))  # an undefined alias: the loader says so
            if named is None:
                raise ConfigError(f"{source}: the alias *{_cut(str(event.anchor), 40)} at {where(event)} is inside the node it "
                                  "names (a recursive value, which no configuration needs)")
            size, height = named
            nodes += size
            if len(open_nodes) + height > MAX_YAML_DEPTH:
                raise ConfigError(f"{source}: YAML nested more than {MAX_YAML_DEPTH} levels deep with its aliases expanded, at "
                                  f"{where(event)} (limit gnc_common.validation.MAX_YAML_DEPTH; sappc's own files nest 8 deep)")
            if open_nodes:
                open_nodes[-1][2] = max(open_nodes[-1][2], height)
        elif kind is DocumentStartEvent:
            anchors.clear()  # an anchor names a node of its own document only
        else:
            continue
        if nodes > MAX_YAML_NODES:
            raise ConfigError(f"{source}: YAML of more than {MAX_YAML_NODES:,} nodes with its aliases expanded, at "
                              f"{where(event)} (limit gnc_common.validation.MAX_YAML_NODES; sappc's own files hold 500)")


def _yaml_problem(exc: Exception) -> str:
    """A YAML error on one line: its problem and where, then what the parser was doing and where."""
    problem = getattr(exc, "problem", None)
    if problem is None:  # not a marked error (a reader error: a character YAML does not allow)
        return _cut(" ".join(str(exc).split()), 200)
    text = _cut(" ".join(str(problem).split()), 120)
    mark = getattr(exc, "problem_mark", None)
    if mark is not None:
        text += f" at line {mark.line + 1}, column {mark.column + 1}"
    context, context_mark = getattr(exc, "context", None), getattr(exc, "context_mark", None)
    if context:
        text += f" ({_cut(' '.join(str(context).split()), 80)}"
        if context_mark is not None:
            text += f" at line {context_mark.line + 1}, column {context_mark.column + 1}"
        text += ")"
    return text


def _cut(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def read_yaml_file(path: str | os.PathLike[str], what: str, *, max_bytes: int = MAX_YAML_BYTES) -> Any:
    """The value of a YAML file: :func:`read_text_file` then :func:`safe_load_yaml`, under their limits.

    Raises
    ------
    ConfigError
        One line naming the file: it cannot be read, is too large, is not UTF-8 text, is not
        YAML, or exceeds a limit of :func:`safe_load_yaml`.
    """
    return safe_load_yaml(read_text_file(path, what, max_bytes=max_bytes), source=str(path))


def read_text_file(path: str | os.PathLike[str], what: str, *, max_bytes: int | None = None) -> str:
    """The text of a configuration file (a scenario, a parameters file), UTF-8 as YAML requires.

    Parameters
    ----------
    path : path-like
        The file.
    what : str
        What the file is, for the message (``"scenario"``, ``"parameters"``).
    max_bytes : int, optional
        The largest file accepted [bytes]; a larger one is refused before it is read whole (let
        alone parsed: a YAML parser takes tens of times a file's size in memory).

    Raises
    ------
    ConfigError
        One line naming the file: it cannot be read, it is larger than ``max_bytes`` (naming its
        size and the limit), or it is not UTF-8 text (naming the first byte that is not, and where).
    """
    try:
        with open(path, "rb") as f:
            data = f.read() if max_bytes is None else f.read(max_bytes + 1)
            size = os.fstat(f.fileno()).st_size
    except OSError as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc.strerror}") from None
    if max_bytes is not None and len(data) > max_bytes:
        stated = f"{size:,} bytes" if size > max_bytes else f"more than {max_bytes:,} bytes"  # a pipe's size is not known
        raise ConfigError(f"{path} is {stated}, more than a {what} file may be ({max_bytes:,} bytes): is it the right file?")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ConfigError(f"{path} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}, line {line}): "
                          f"save the {what} as UTF-8") from None


def holds_bool(value: Any) -> bool:
    """Whether ``value`` is a ``bool`` or holds one (in a list, tuple or mapping, at any depth, or
    a numpy boolean array): YAML reads ``true`` as a boolean, and ``bool`` is an ``int`` in Python,
    so a number check alone would take ``true`` for 1."""
    if isinstance(value, (bool, np.bool_)):
        return True
    if isinstance(value, np.ndarray):
        return bool(value.dtype == np.bool_)
    if isinstance(value, (list, tuple)):
        return any(holds_bool(v) for v in value)
    if isinstance(value, dict):
        return any(holds_bool(v) for v in value.values())
    return False


def _describe(value: Any) -> str:
    arr = np.asarray(value)
    if arr.size <= 12:
        return np.array2string(arr, precision=6, separator=", ")
    return f"array of shape {arr.shape}"


def as_finite_array(name: str, value: ArrayLike, *, shape_tail: tuple[int, ...] = ()) -> NDArray[np.float64]:
    """Return ``value`` as a float64 array after checking shape and finiteness.

    Parameters
    ----------
    name : str
        Name used in the error message (e.g. ``"omega_BN_B"``).
    value : array_like
        The input.
    shape_tail : tuple of int
        Required trailing shape, e.g. ``(3,)``; leading (batch) axes are free.

    Raises
    ------
    InputError
        If the trailing shape is wrong, any element is NaN or infinite, or a boolean is given.
    """
    if not isinstance(value, np.ndarray) or value.dtype == np.bool_:  # (a float array, the run-time case, holds no bool)
        if holds_bool(value):
            raise InputError(f"{name} must be numeric, got {quoted(value)} (a boolean is not a number)")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numeric, got {quoted(value)}") from exc
    if shape_tail and arr.shape[arr.ndim - len(shape_tail):] != shape_tail:
        raise InputError(f"{name} must have trailing shape {shape_tail}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise InputError(f"{name} contains a non-finite value {arr[tuple(bad)]} at index {tuple(int(i) for i in bad)}: {_describe(arr)}")
    return arr


def check_unit_quaternion(name: str, value: ArrayLike, *, tol: float = QUATERNION_NORM_TOL) -> NDArray[np.float64]:
    """Check a (batch of) scalar-last quaternion(s) is finite and of unit norm.

    Raises
    ------
    InputError
        If any quaternion is zero, non-finite, or its norm differs from 1 by more than ``tol``.
    """
    if isinstance(value, np.ndarray) and value.shape == (4,) and value.dtype == np.float64:
        # one quaternion (the controller node checks two every sample): the same sum in the same
        # order as below, in Python floats; NaN or infinity fails the comparison and is reported below
        x, y, z, w = value.tolist()
        if abs(math.sqrt(x * x + y * y + z * z + w * w) - 1.0) <= tol:
            return value
    q = as_finite_array(name, value, shape_tail=(4,))
    rows = q.reshape(-1, 4)
    norm = np.sqrt(np.sum(rows * rows, axis=-1))
    bad = np.flatnonzero(np.abs(norm - 1.0) > tol)
    if bad.size:
        k = int(bad[0])
        where = f" (run {k})" if q.ndim > 1 else ""
        raise InputError(
            f"{name}{where} must be a unit quaternion (x, y, z, w), got {_describe(rows[k])} with norm {norm[k]:.9g}"
        )
    return q


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> Any:
    """Check that ``value`` is finite and positive; return it as a float, or as a float array when
    it holds one value per run (Monte Carlo dispersions of a batch); a boolean is not a number."""
    if holds_bool(value):
        raise ConfigError(f"{name} must be a number, got {quoted(value)} (a boolean is not a number)")
    try:
        x = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be a number, got {quoted(value)}") from exc
    if not np.all(np.isfinite(x)) or np.any(x < 0.0 if allow_zero else x <= 0.0):
        rel = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{name} must be finite and {rel}, got {quoted(value)}")
    return float(x) if x.ndim == 0 else x


def check_initial_quaternion(name: str, value: Any, *, tol: float = INITIAL_QUATERNION_NORM_TOL) -> NDArray[np.float64]:
    """Check an initial attitude typed by hand and return it normalised.

    Parameters
    ----------
    name : str
        Name used in the error message (e.g. ``"initial_state.q_BN"``).
    value : array_like
        Scalar-last quaternion ``(x, y, z, w)``.
    tol : float
        Largest accepted | ||q|| - 1 | (default :data:`INITIAL_QUATERNION_NORM_TOL`).

    Returns
    -------
    ndarray (4,)
        ``value / ||value||``.

    Raises
    ------
    InputError
        If it is not 4 finite numbers.
    ConfigError
        If its norm differs from 1 by more than ``tol`` (a typo, not rounding).
    """
    q = as_finite_array(name, value, shape_tail=(4,))
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > tol:
        raise ConfigError(f"{name} = {quoted(q.tolist())} has norm {norm:.6g}; expected a unit quaternion (x, y, z, w)")
    return q / norm


def check_positive_int(name: str, value: Any) -> int:
    """Check that ``value`` is an integer >= 1 (a count: substeps, samples) and return it.

    Raises
    ------
    ConfigError
        If it is not an ``int`` (a ``bool`` or a float is refused) or is less than 1.
    """
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ConfigError(f"{name} must be a positive integer, got {quoted(value)}")
    return value


#: Relative slack of the triangle inequality of principal moments, ``I1 + I2 >= I3 (1 - rtol)``:
#: the eigenvalues of a symmetric 3x3 matrix carry ~1e-15 relative rounding, so a flat plate
#: (equality) written with rounded moments still passes.
INERTIA_TRIANGLE_RTOL = 1e-9


def check_spd_inertia(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """Check an inertia matrix (3x3, or a batch (..., 3, 3)) is physical: symmetric positive
    definite, and its principal moments satisfy the triangle inequality ``I1 + I2 >= I3``.

    Symmetry is required to 1e-9 relative to the largest element; positive
    definiteness is tested with a Cholesky factorisation.

    Raises
    ------
    ConfigError
        Naming the matrix and its eigenvalues when the check fails.
    """
    if holds_bool(value):
        raise ConfigError(f"{name} must be a 3x3 numeric matrix, got {quoted(value)} (a boolean is not a number)")
    try:
        J = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be a 3x3 numeric matrix, got {quoted(value)}") from exc
    if J.shape[-2:] != (3, 3):
        raise ConfigError(f"{name} must be 3x3 (or a batch of 3x3), got shape {J.shape}")
    if not np.all(np.isfinite(J)):
        raise ConfigError(f"{name} contains a non-finite value: {_describe(J)}")
    scale = np.max(np.abs(J))
    if not np.allclose(J, np.swapaxes(J, -1, -2), rtol=0.0, atol=1e-9 * max(scale, 1e-300)):
        raise ConfigError(f"{name} must be symmetric, got {_describe(J)}")
    try:
        np.linalg.cholesky(J)
    except np.linalg.LinAlgError:
        eig = np.linalg.eigvalsh(J.reshape(-1, 3, 3))
        raise ConfigError(f"{name} must be positive definite; its eigenvalues are {_describe(eig)}") from None
    moments = np.linalg.eigvalsh(J.reshape(-1, 3, 3))  # ascending principal moments, per matrix
    thin = moments[:, 0] + moments[:, 1] < moments[:, 2] * (1.0 - INERTIA_TRIANGLE_RTOL)
    if np.any(thin):
        k = int(np.argmax(thin))
        raise ConfigError(
            f"{name} is not the inertia of a rigid body: its principal moments {_describe(moments[k])} kg m^2 violate the "
            f"triangle inequality I1 + I2 >= I3 (every mass distribution satisfies it; equality is a flat plate)"
            + (f" (matrix {k} of the batch)" if J.ndim > 2 else "")
        )
    return J


def inertia_from_row_major(name: str, value: Any) -> NDArray[np.float64]:
    """An inertia given as 9 numbers, row major (a ROS parameter), as a 3x3 matrix.

    Only the count is checked here; whoever builds on the matrix checks it with
    :func:`check_spd_inertia` (the plant core, the controller configs), as for a scenario file.

    Parameters
    ----------
    name : str
        Name used in the error message (e.g. ``"inertia_kg_m2"``).
    value : array_like
        ``[J11, J12, J13, J21, ..., J33]`` [kg m^2].

    Returns
    -------
    ndarray (3, 3)
        The matrix [kg m^2].

    Raises
    ------
    ConfigError
        If it is not 9 numbers.
    """
    if holds_bool(value):
        raise ConfigError(f"{name} must be 9 numbers (row major 3x3), got {quoted(value)} (a boolean is not a number)")
    try:
        flat = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be 9 numbers (row major 3x3), got {quoted(value)}") from exc
    if flat.size != 9:
        raise ConfigError(f"{name} must have 9 values (row major 3x3), got {flat.size}")
    return flat.reshape(3, 3)


def from_mapping(cls: type, data: Any, prefix: str) -> Any:
    """Build the frozen dataclass ``cls`` from a mapping (parsed YAML), strictly.

    Nested dataclass fields are built recursively; lists become tuples (so the
    result stays hashable and immutable).  The dataclass's own ``__post_init__``
    then validates the values.

    Parameters
    ----------
    cls : type
        A dataclass.
    data : mapping
        Its fields by name.
    prefix : str
        Dotted path of ``data`` in the file, used in error messages.

    Raises
    ------
    ConfigError
        For a non-mapping, an unknown key (naming it and the accepted keys), a missing required
        key, or a boolean (``true``) given where the field's type expects numbers (naming the key).
    """
    import dataclasses
    import typing

    if not isinstance(data, dict):
        raise ConfigError(f"{prefix} must be a mapping, got {quoted(data)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields), key=str)  # keys of any type (YAML allows `1:`)
    if unknown:
        raise ConfigError(f"unknown key {prefix}.{_cut(str(unknown[0]), 60)}; {prefix} accepts {', '.join(sorted(fields))}")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"missing key {prefix}.{name}")
            continue
        value = data[name]
        hint = hints[name]
        if _expects_number(hint) and holds_bool(value):
            where, leaf = _first_bool(value)
            raise ConfigError(f"{prefix}.{name}{where} must be a number, got {quoted(leaf)} (a boolean is not a number)")
        # a dataclass field, or an optional one (``SomeDataclass | None``)
        options = [h for h in typing.get_args(hint) if h is not type(None)] if typing.get_args(hint) else [hint]
        nested = options[0] if len(options) == 1 and isinstance(options[0], type) and dataclasses.is_dataclass(options[0]) else None
        enum = options[0] if len(options) == 1 and isinstance(options[0], type) and issubclass(options[0], Enum) else None
        if nested is not None and value is not None:
            kwargs[name] = from_mapping(nested, value, f"{prefix}.{name}")
        elif enum is not None and value is not None:
            try:
                kwargs[name] = enum(value)
            except ValueError:
                accepted = ", ".join(repr(m.value) for m in enum)
                raise ConfigError(f"{prefix}.{name} must be one of {accepted}, got {quoted(value)}") from None
        else:
            kwargs[name] = _freeze(value)
    try:
        return cls(**kwargs)
    except (ConfigError, InputError) as exc:  # a bad value in a file is a configuration error
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(prefix) else f"{prefix}: {msg}") from None
    except TypeError as exc:
        raise ConfigError(f"{prefix}: {exc}") from None


def _first_bool(value: Any) -> tuple[str, Any]:
    """Where the first boolean inside ``value`` is (``".key"``, ``"[2]"``, ``""`` for ``value``
    itself) and the boolean, for a message that names the key at fault (:func:`holds_bool`)."""
    if isinstance(value, dict):
        for k, v in value.items():
            if holds_bool(v):
                where, leaf = _first_bool(v)
                return f".{_cut(str(k), 60)}{where}", leaf
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            if holds_bool(v):
                where, leaf = _first_bool(v)
                return f"[{i}]{where}", leaf
    return "", value


def _leaf_types(hint: Any) -> set[Any]:
    """The types a field's hint allows at its leaves (``tuple[float, ...] | None`` -> {float, None})."""
    import typing

    args = typing.get_args(hint)
    if not args:
        return {hint}
    out: set[Any] = set()
    for a in args:
        if a is not Ellipsis:
            out |= _leaf_types(a)
    return out


def _expects_number(hint: Any) -> bool:
    """Whether a field typed ``hint`` holds numbers and never a boolean (a ``bool`` field, or an
    ``Any`` one, may hold ``true``)."""
    leaves = _leaf_types(hint)
    return bool(leaves & {int, float}) and not leaves & {bool, Any, object}


def _freeze(value: Any) -> Any:
    if isinstance(value, list):
        return tuple(_freeze(v) for v in value)
    return value


def from_kind_list(entries: Any, kinds: dict[str, type], prefix: str) -> tuple[Any, ...]:
    """Build ``[{kind: ..., <fields>}, ...]`` (a scenario's ``disturbances:`` or ``faults:``) with
    :func:`from_mapping`, one dataclass of ``kinds[kind]`` per entry; ``None`` is an empty list.

    Raises
    ------
    ConfigError
        Naming the entry (``faults[2]``) and, where it applies, the key.
    """
    if entries is None:
        return ()
    if not isinstance(entries, list):
        raise ConfigError(f"{prefix} must be a list, got {quoted(entries)}")
    out = []
    for i, entry in enumerate(entries):
        where = f"{prefix}[{i}]"
        if not isinstance(entry, dict) or "kind" not in entry:
            raise ConfigError(f"{where} must be a mapping with a 'kind' key, got {quoted(entry)}")
        kind = entry["kind"]
        if kind not in kinds:
            raise ConfigError(f"{where}.kind = {quoted(kind)} is unknown; expected one of {sorted(kinds)}")
        try:
            out.append(from_mapping(kinds[kind], {k: v for k, v in entry.items() if k != "kind"}, where))
        except ConfigError as exc:  # a field's own check does not know which entry it is in
            msg = str(exc)
            raise ConfigError(msg if msg.startswith(("unknown key", "missing key", where)) else f"{where}: {msg}") from None
    return tuple(out)
