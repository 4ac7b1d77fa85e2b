"""The report page (``sappc report``'s ``report.html``), on synthetic bags: the run's parameters as
the bag records them (the controller's in a table, both files folded), one sentence beside each
metric and what a ``-`` means; a bag without the records says it has none."""

from __future__ import annotations

import html
import re
from pathlib import Path

import pytest
import yaml
from bagmaker import write_bag

from sappc.analysis.report import METRIC_SENTENCES, NOT_APPLICABLE, analyse_bag, write_report
from sappc.bag.read import PARAMS_RECORD, SCENARIO_RECORD
from sappc.graph.launch import node_parameters
from sappc.scenario import load_scenario
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import quaternion_msg, torque_msg, vector3_msg

from conftest import SCENARIOS
from figure_checks import NO_EMPTY_LOG_AXES

pytestmark = NO_EMPTY_LOG_AXES  # the report draws its figures in this process


def _bag(path: Path, metadata: dict[str, dict[str, str]]) -> Path:
    """50 samples at 100 Hz of a body at rest on the identity reference."""
    messages = []
    for k in range(50):
        ts = 0.01 * k
        messages += [
            (c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], ts, c.STATE_ATTITUDE), k),
            (c.STATE_RATE.name, c.STATE_RATE.type_name, vector3_msg([0.0, 0.0, 0.0], ts, c.STATE_RATE), k),
            (c.REFERENCE_ATTITUDE.name, c.REFERENCE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], ts, c.REFERENCE_ATTITUDE), k),
            (c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg([0.01, 0.0, -0.02], ts, c.CONTROL_TORQUE), k),
        ]
    return write_bag(path, messages, metadata=metadata)


def _cells(page: str) -> list[list[str]]:
    """Every table row of the page, as its cells' text."""
    return [[html.unescape(cell) for cell in re.findall(r"<td>(.*?)</td>", row)] for row in re.findall(r"<tr>(.*?)</tr>", page)]


def test_the_page_shows_the_recorded_parameters_and_a_sentence_per_metric(tmp_path: Path) -> None:
    scenario_text = (SCENARIOS / "paper_tracking.yaml").read_text()
    scenario = load_scenario(SCENARIOS / "paper_tracking.yaml")
    params = node_parameters(scenario, scenario.resolve_controller(None), realtime=False,
                             paths={"scenario": "scenario.yaml", "bag": "bag", "counts": "counts", "params": "params.yaml", "end": "e"})
    params_text = yaml.safe_dump(params, sort_keys=False)
    a = analyse_bag(_bag(tmp_path / "b.mcap", {SCENARIO_RECORD: {"text": scenario_text}, PARAMS_RECORD: {"text": params_text}}))
    write_report(a, tmp_path / "report")
    page = (tmp_path / "report" / "report.html").read_text()
    rows = {r[0]: r[1:] for r in _cells(page) if r}
    gains = scenario.raw["controllers"]["sappc"]["gains"]
    assert rows["sappc.gains.K_q"] == [f"{gains['K_q']:g}"] and rows["sappc.rpf.l"] == [f"{scenario.raw['controllers']['sappc']['rpf']['l']:g}"]
    assert rows["controller"] == ["sappc"] and "counts_file" not in rows and "expected_subscribers" not in rows  # plumbing left out
    assert f"<summary>{PARAMS_RECORD} as recorded</summary><pre>{html.escape(params_text)}</pre>" in page
    assert f"<summary>{SCENARIO_RECORD} as recorded</summary><pre>{html.escape(scenario_text)}</pre>" in page
    assert a.metrics is not None
    for name, value in a.metrics.items():
        assert rows[name][1] == METRIC_SENTENCES[name], name
    assert rows["returned_at_s"][0] == "-" and "None" not in page and html.escape(NOT_APPLICABLE) in page


def test_a_bag_without_the_records_says_it_has_no_parameters(tmp_path: Path) -> None:
    a = analyse_bag(_bag(tmp_path / "b.mcap", {}))
    write_report(a, tmp_path / "report")
    page = (tmp_path / "report" / "report.html").read_text()
    assert f"The bag records no parameters (no {PARAMS_RECORD} or {SCENARIO_RECORD} metadata record" in page
    assert "<details>" not in page


@pytest.mark.parametrize("broken", ["/controller: [unclosed\n", "just text\n"])
def test_a_params_record_that_is_not_the_nodes_mapping_is_still_shown_as_recorded(tmp_path: Path, broken: str) -> None:
    a = analyse_bag(_bag(tmp_path / "b.mcap", {PARAMS_RECORD: {"text": broken}}))
    write_report(a, tmp_path / "report")
    page = (tmp_path / "report" / "report.html").read_text()
    assert f"<pre>{html.escape(broken)}</pre>" in page and "The controller node's parameters" not in page
