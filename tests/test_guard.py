"""The guard on the reproductions (experiments/guard.py): results/ is never worse than its record
beyond a metric's noise band, and the record moves down only with a reason."""

import json

import pytest

from experiments import guard


def test_results_within_their_record():
    """CI's check of what results/ holds: `make repro-check` exits 0."""
    assert guard.check(guard.load_record()) == []


def test_every_guarded_result_is_recorded():
    record = guard.load_record()
    for name, metrics in guard.METRICS.items():
        for metric in metrics:
            assert metric.path in record.get(name, {}), f"{name}.{metric.path} has no record"
            assert metric.band >= 0 and metric.why


@pytest.fixture
def sandbox(tmp_path, monkeypatch):
    """A results/ of one experiment with one guarded metric, in a temporary directory."""
    monkeypatch.setattr(guard, "RESULTS", tmp_path)
    monkeypatch.setattr(guard, "RECORD", tmp_path / "record.json")
    monkeypatch.setattr(guard, "METRICS", {"demo": [guard.Metric("joint", "lower", 0.1, "test")]})
    (tmp_path / "demo").mkdir()

    def write(value):
        (tmp_path / "demo" / "result.json").write_text(
            json.dumps({"joint": value, "stamp": {"commit": "abc1234"}})
        )

    return write


def test_a_worse_result_fails_and_a_better_one_raises_the_record(sandbox):
    sandbox(1.0)
    record = {}
    assert guard.update(record) == ["demo.joint: 1"]
    assert guard.check(record) == []
    sandbox(1.05)  # inside the band of 0.1: noise
    assert guard.check(record) == [] and guard.update(record) == []
    sandbox(1.2)  # past it
    (problem,) = guard.check(record)
    assert "1.2 is worse than the best recorded 1" in problem and "--accept demo" in problem
    sandbox(0.5)
    assert guard.update(record) == ["demo.joint: 0.5"] and record["demo"]["joint"]["best"] == 0.5


def test_a_deliberate_change_is_accepted_with_its_reason(sandbox):
    sandbox(0.5)
    record = {}
    guard.update(record)
    sandbox(2.0)
    assert guard.check(record)
    guard.accept(record, "demo", "the element bound on by default")
    assert guard.check(record) == []
    assert record["demo"]["joint"] == {
        "best": 2.0,
        "commit": "abc1234",
        "accepted": "the element bound on by default",
    }


def test_a_recorded_metric_missing_from_results_is_named(sandbox):
    sandbox(0.5)
    record = {}
    guard.update(record)
    (guard.RESULTS / "demo" / "result.json").write_text(json.dumps({"stamp": {}}))
    (problem,) = guard.check(record)
    assert "missing from results/demo/result.json" in problem


def test_higher_is_better_metrics_fail_downwards():
    metric = guard.Metric("x", "higher", 0.01, "test")
    assert guard.worse(metric, 0.904, 0.932) and not guard.worse(metric, 0.925, 0.932)
    assert guard.improves(metric, 0.94, 0.932) and not guard.improves(metric, 0.93, 0.932)
