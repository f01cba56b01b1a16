"""The bridge tests' marker: ``record(*topics)`` names the topics a test's probe node records."""

from __future__ import annotations


def pytest_configure(config):
    config.addinivalue_line("markers", "record(*keys): the topics the probe node records (keys of test_ros.Probe.TOPICS)")
