"""The suite's compile flags (``compile_level.py``): fast tests compile at -O0, a run that selects
the slow tests keeps XLA's defaults (they train RESULTS.md's rows, whose times were measured at
the defaults, and the scripts they start inherit ``XLA_FLAGS``)."""

import compile_level
import pytest


@pytest.mark.parametrize(
    ("markexpr", "slow"),
    [
        ("", False),
        ("not slow", False),
        ("not  slow", False),
        ("slow", True),
        ("slow and not gpu", True),
        ("slow or not slow", True),
    ],
)
def test_a_mark_expression_that_selects_slow_tests_is_recognised(markexpr, slow):
    assert compile_level.selects_slow(markexpr) is slow


def test_apply_adds_the_flags_for_fast_tests_and_not_for_slow_ones(monkeypatch):
    monkeypatch.delenv("TEST_XLA_OPT", raising=False)
    monkeypatch.setattr(compile_level, "_accelerator_plugin", lambda: False)
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    compile_level.apply("slow")
    assert compile_level.FLAG not in compile_level.os.environ["XLA_FLAGS"]
    compile_level.apply("not slow")
    flags = compile_level.os.environ["XLA_FLAGS"].split()
    assert flags[0] == "--xla_force_host_platform_device_count=2"
    assert compile_level.FLAG in flags
    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.setenv("TEST_XLA_OPT", "default")
    compile_level.apply("not slow")
    assert compile_level.os.environ["XLA_FLAGS"] == ""
