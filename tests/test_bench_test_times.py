"""bench/test_times.py reads a .ci/run log: two pytest runs, their slowest tests and the total."""
import importlib.util

import pytest

from tests.conftest import ROOT

spec = importlib.util.spec_from_file_location("test_times", ROOT / "bench" / "test_times.py")
test_times = importlib.util.module_from_spec(spec)
spec.loader.exec_module(test_times)

LOG = """\
ci: commit abc1234
....                                                                     [100%]
============================= slowest 15 durations =============================
4.16s call     tests/test_a.py::test_one
1.50s setup    tests/test_b.py::test_two
301 passed in 69.83s (0:01:09)
..s.
============================= slowest 15 durations =============================
563.05s setup    tests/test_held.py::test_goals
46 passed, 2 skipped, 292 deselected in 1205.85s (0:20:05)
ci: finished in 1450 s (install, docs build, fast and slow tests)
"""


def test_the_two_runs_their_slowest_tests_and_the_total():
    t = test_times.parse_log(LOG)
    fast, slow = t["runs"]
    assert (fast["passed"], fast["skipped"], fast["seconds"]) == (301, 0, 69.83)
    assert [r["test"] for r in fast["slowest"]] == ["tests/test_a.py::test_one", "tests/test_b.py::test_two"]
    assert (slow["passed"], slow["skipped"], slow["seconds"]) == (46, 2, 1205.85)
    assert slow["slowest"] == [dict(test="tests/test_held.py::test_goals", when="setup", seconds=563.05)]
    assert t["total_seconds"] == 1450 and t["commit"] == "abc1234"


def test_a_log_of_a_failed_run_is_refused():
    with pytest.raises(ValueError, match="found 1 runs"):
        test_times.parse_log(LOG.split("..s.")[0])
