"""The one YAML loader (:func:`gnc_common.validation.safe_load_yaml`, issue 46 item 3): the values
``yaml.safe_load`` gives, for every file sappc ships; and, before anything is built, a refusal in
one line naming the source and the limit for a text past its size, its nesting or its node count
with aliases expanded, and for a recursive alias; YAML errors in one line with line and column.

Each limit is tested at its edge (the last accepted text and the first refused); the counts with
aliases against a hand count on small texts, the limit lowered with ``monkeypatch``."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest
import yaml

import gnc_common.validation as v
from bad_yaml import LIMIT, bad_yaml_texts
from conftest import ROOT
from gnc_common.validation import (MAX_MESSAGE_CHARS, MAX_QUOTED_CHARS, MAX_YAML_DEPTH, MAX_YAML_NODES, ConfigError, quoted,
                                   read_yaml_file, safe_load_yaml)

#: Every YAML file sappc ships: the scenarios and the nodes' parameter files.
SHIPPED = sorted((ROOT / "src" / "sappc" / "data").rglob("*.yaml"))


def _refusal(text: str, source: str = "t.yaml") -> str:
    with pytest.raises(ConfigError) as exc:
        safe_load_yaml(text, source=source)
    message = str(exc.value)
    assert "\n" not in message and message.startswith(source), message
    return message


def _nested(depth: int) -> str:
    """A flow sequence ``depth`` levels deep (a scalar at the bottom)."""
    return "[" * depth + "1" + "]" * depth


def test_every_shipped_file_loads_to_the_value_yaml_safe_load_gives() -> None:
    assert len(SHIPPED) >= 20
    for path in SHIPPED:
        text = path.read_text()
        assert safe_load_yaml(text, source=str(path)) == yaml.safe_load(text), path


def test_anchors_aliases_and_merge_keys_load_as_yaml_safe_load_loads_them() -> None:
    text = "base: &b {k: 1.5, kd: [1, 2]}\nother: *b\nmerged:\n  <<: *b\n  k: 3\nsame: [&x 7, *x]\n"
    assert safe_load_yaml(text) == yaml.safe_load(text) == {
        "base": {"k": 1.5, "kd": [1, 2]}, "other": {"k": 1.5, "kd": [1, 2]}, "merged": {"k": 3, "kd": [1, 2]}, "same": [7, 7]}


def test_nesting_at_the_limit_loads_and_one_level_more_is_refused_naming_the_limit() -> None:
    # the depth counts sequences and mappings; a mapping at the top is one level
    assert safe_load_yaml(_nested(MAX_YAML_DEPTH)) == yaml.safe_load(_nested(MAX_YAML_DEPTH))
    assert safe_load_yaml("a: " + _nested(MAX_YAML_DEPTH - 1))["a"] is not None
    message = _refusal("a: " + _nested(MAX_YAML_DEPTH))
    assert f"nested more than {MAX_YAML_DEPTH} levels deep at line 1, column {4 + MAX_YAML_DEPTH - 1}" in message
    assert "MAX_YAML_DEPTH" in message
    _refusal(_nested(MAX_YAML_DEPTH + 1))


def test_an_alias_nests_as_deep_as_the_node_it_names() -> None:
    half = MAX_YAML_DEPTH // 2
    anchored = f"a: &a {_nested(half - 1)}\n"  # height half - 1, inside the top mapping
    at_limit = anchored + f"b: {'[' * (MAX_YAML_DEPTH - half)}*a{']' * (MAX_YAML_DEPTH - half)}\n"
    assert safe_load_yaml(at_limit) == yaml.safe_load(at_limit)
    over = anchored + f"b: {'[' * (MAX_YAML_DEPTH - half + 1)}*a{']' * (MAX_YAML_DEPTH - half + 1)}\n"
    assert "aliases expanded" in _refusal(over)


def test_the_node_count_at_the_limit_loads_and_one_more_is_refused() -> None:
    # a flow sequence of n scalars is n + 1 nodes
    at_limit = "[" + ", ".join(["0"] * (MAX_YAML_NODES - 1)) + "]"
    assert len(safe_load_yaml(at_limit)) == MAX_YAML_NODES - 1
    message = _refusal("[" + ", ".join(["0"] * MAX_YAML_NODES) + "]")
    assert f"more than {MAX_YAML_NODES:,} nodes" in message and "MAX_YAML_NODES" in message


def test_an_alias_counts_as_every_node_it_names(monkeypatch: pytest.MonkeyPatch) -> None:
    # mapping 1, key a 1, sequence 1 + 3 scalars, key b 1, alias of 4 nodes, key c 1, alias of 4: 16 nodes
    text = "a: &a [1, 2, 3]\nb: *a\nc: *a\n"
    monkeypatch.setattr(v, "MAX_YAML_NODES", 16)
    assert safe_load_yaml(text) == {"a": [1, 2, 3], "b": [1, 2, 3], "c": [1, 2, 3]}
    monkeypatch.setattr(v, "MAX_YAML_NODES", 15)
    assert "line 3, column 4" in _refusal(text)  # at the alias that passes the limit


def test_an_alias_of_an_alias_counts_the_expansion_of_both(monkeypatch: pytest.MonkeyPatch) -> None:
    # x: [s, s] (3 nodes), y: [*x, *x] (1 + 2 * 3 = 7 nodes), z: *y (7): 1 + 3 keys + 3 + 7 + 7 = 21 nodes
    text = "x: &x [&s q, *s]\ny: &y [*x, *x]\nz: *y\n"
    monkeypatch.setattr(v, "MAX_YAML_NODES", 21)
    assert safe_load_yaml(text) == yaml.safe_load(text)
    monkeypatch.setattr(v, "MAX_YAML_NODES", 20)
    _refusal(text)


def test_an_alias_inside_the_node_it_names_is_refused() -> None:
    assert "inside the node it names" in _refusal("a: &a [1, *a]\n")
    assert "*loop" in _refusal("a: &loop {b: [*loop]}\n")


def test_a_text_past_the_size_limit_is_refused_before_it_is_parsed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(v, "MAX_YAML_BYTES", 10)
    assert safe_load_yaml("a: 1234567") == {"a": 1234567}
    assert "MAX_YAML_BYTES" in _refusal("a: [12345678")  # not parsed: its YAML error is not the message


@pytest.mark.parametrize(("text", "words"), [
    ("a: [1, 2\n", "expected ',' or ']', but got '<stream end>' at line 2, column 1 (while parsing a flow sequence at line 1, column 4)"),
    ("a: b: c\n", "mapping values are not allowed here at line 1, column 5"),
    ("a:\n\t- 1\n", "found character '\\t' that cannot start any token at line 2, column 1"),
    ("a: *nowhere\n", "found undefined alias 'nowhere' at line 1, column 4"),
    ("a: !!python/object:os.system x\n", "could not determine a constructor for the tag"),
    ("--- 1\n--- 2\n", "but found another document at line 2, column 1"),
    ("a: &x 1\nb: &x 2\n", "found duplicate anchor 'x'"),
])
def test_a_yaml_error_is_one_line_with_pyyamls_words_and_where(text: str, words: str) -> None:
    message = _refusal(text)
    assert message.startswith("t.yaml is not valid YAML: ") and words in message, message


def test_a_large_text_keeps_libyamls_error_rather_than_parse_it_again_slowly(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(v, "YAML_REPARSE_BYTES", 0)
    assert "did not find expected ',' or ']' at line 2, column 1" in _refusal("a: [1, 2\n")


def test_the_pure_python_loader_keeps_the_same_limits_and_values(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delattr(yaml, "CSafeLoader")
    text = SHIPPED[0].read_text()
    assert safe_load_yaml(text) == yaml.safe_load(text)
    for name, bad in bad_yaml_texts().items():
        assert LIMIT[name] in _refusal(bad), name


@pytest.mark.parametrize("name", sorted(LIMIT))
def test_each_file_of_the_issue_is_refused_by_its_limit_in_a_short_line(name: str) -> None:
    message = _refusal(bad_yaml_texts()[name], source=f"{name}.yaml")
    assert LIMIT[name] in message and len(message) < 250, message


def test_a_value_in_a_message_is_quoted_short() -> None:
    assert quoted([0.1, 0.2, 0.3, 1.0]) == repr([0.1, 0.2, 0.3, 1.0])
    assert quoted([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) == repr([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    shared = ["lol" * 10] * 10
    for level in range(5):
        shared = [shared] * 10  # a million strings, shared as aliases share them
    assert len(quoted(shared)) <= MAX_QUOTED_CHARS
    assert len(quoted("x" * 10**6)) <= MAX_QUOTED_CHARS
    assert "\n" not in quoted("one\ntwo")


def test_a_number_check_quotes_a_value_short_and_names_the_key_of_a_boolean_inside_it() -> None:
    with pytest.raises(ConfigError) as exc:
        v.check_positive("rho_e0", ["x"] * 10**5)
    assert len(str(exc.value)) < 200
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class Limits:
        bounds: dict[str, float]

    with pytest.raises(ConfigError, match=r"^limits\.bounds\.b must be a number, got True \(a boolean is not a number\)$"):
        v.from_mapping(Limits, {"bounds": {"a": 1.0, "b": True}}, "limits")


def test_a_config_error_is_one_line_of_bounded_length_and_survives_pickling() -> None:
    assert str(ConfigError("a\nb")) == "a b"
    long = ConfigError("start " + "x" * 10**6 + " end")
    text = str(long)
    assert len(text) <= MAX_MESSAGE_CHARS and text.startswith("start ") and text.endswith(" end") and "characters cut" in text
    assert str(pickle.loads(pickle.dumps(long))) == text  # as a campaign's worker sends it back
    assert ConfigError("short").args == ("short",)


def test_read_yaml_file_names_the_file_it_cannot_read(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^cannot read parameters .*: Is a directory$"):
        read_yaml_file(tmp_path, "parameters")
    (tmp_path / "p.yaml").write_text("a: [1\n")
    with pytest.raises(ConfigError, match=r"p\.yaml is not valid YAML: .* at line 2, column 1"):
        read_yaml_file(tmp_path / "p.yaml", "parameters")
