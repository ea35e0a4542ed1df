"""The node's statistics and its /diagnostics values, without ROS: counts, rates, latencies and the telemetry."""

from __future__ import annotations

from moseg_ros.diagnostics import NodeStatistics, rate, telemetry_values


def test_the_methods_telemetry_is_published_as_it_comes_last_max_and_mean_per_key():
    recent = [{}, {"refit_age": 0}, {"refit_age": 2, "fusion_age": 1, "fusion_seconds": 0.0123}, {"refit_age": 1}]
    assert telemetry_values(recent) == {
        "refit_age_last": "1", "refit_age_max": "2", "refit_age_mean": "1.00",
        "fusion_age_last": "1", "fusion_age_max": "1", "fusion_age_mean": "1.00",
        "fusion_seconds_last": "0.0123", "fusion_seconds_max": "0.0123", "fusion_seconds_mean": "0.01"}
    assert telemetry_values([{}, {}]) == {}


def test_rate_over_the_events_times():
    assert rate([]) == rate([5.0]) == rate([2.0, 2.0]) == 0.0
    assert rate([0.0, 0.1, 0.2, 0.3]) == 10.0


def test_a_frame_counted_in_out_with_its_status_latency_and_telemetry():
    statistics = NodeStatistics()
    for i in range(3):
        statistics.arrived(i * 0.1)
        statistics.processed("ok" if i else "warmup", {"refit_age": i})
        statistics.published(i * 0.1, i * 0.1 + 0.02)
    statistics.processed("failed: ValueError: x", {})
    statistics.counters.failures += 1
    values = statistics.values()
    assert (values["frames_in"], values["frames_out"], values["failures"]) == (3, 3, 1)
    assert statistics.counters.problems == 1
    assert values["input_rate_hz"] == "10.00" and values["latency_ms_p50"] == "20.0"
    assert (values["status_ok"], values["status_warmup"], values["status_failed"]) == (2, 1, 1)
    assert values["refit_age_max"] == "2"
