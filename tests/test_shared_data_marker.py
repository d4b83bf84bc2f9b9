"""The shared_data marker (tests/shared_data.py): skipped without the shared folder; a skip of such a test fails the
run in CI while the folder exists, and always with T2M_REQUIRE_SHARED=1. Checked on a small suite run by pytester."""
from __future__ import annotations

import pytest

from tests.shared_data import REPO, shared_dir

pytest_plugins = ["pytester"]

SUITE = """
import pytest
from tests.shared_data import require_shared

@pytest.mark.shared_data
def test_folder():
    pass

@pytest.mark.shared_data
def test_file():
    require_shared("data", "absent.bin")

@pytest.mark.shared_data
def test_expected_failure():
    pytest.xfail("not about the data")

def test_unmarked_skip():
    pytest.skip("nothing to do with shared data")
"""


@pytest.fixture
def suite(pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch):
    """Runs SUITE with tests/shared_data.py's hooks; returns run(shared folder present?, env) -> outcomes."""
    pytester.makeconftest("from tests.shared_data import pytest_runtest_makereport, pytest_runtest_setup\n")
    pytester.makeini("[pytest]\nmarkers =\n    shared_data: needs the shared folder\n")
    pytester.makepyfile(test_suite=SUITE)
    monkeypatch.syspath_prepend(str(REPO))
    shared = pytester.path / "shared"

    def run(present: bool, **env: str) -> tuple[dict[str, int], str]:
        for name in ("CI", "T2M_REQUIRE_SHARED"):
            monkeypatch.delenv(name, raising=False)
        for name, value in env.items():
            monkeypatch.setenv(name, value)
        if present:
            shared.mkdir(exist_ok=True)
        monkeypatch.setenv("T2M_SHARED", str(shared))
        result = pytester.runpytest("-rA")
        return result.parseoutcomes(), result.stdout.str()
    return run


def test_without_the_folder_the_tests_skip_even_in_ci(suite):
    outcomes, out = suite(False, CI="true")
    assert outcomes == {"skipped": 4}
    assert "shared folder not found at" in out


def test_with_the_folder_outside_ci_a_missing_file_skips(suite):
    outcomes, out = suite(True)
    assert outcomes == {"passed": 1, "skipped": 2, "xfailed": 1}
    assert "shared data not found:" in out and "absent.bin" in out


def test_in_ci_with_the_folder_a_skip_fails(suite):
    outcomes, out = suite(True, CI="true")
    assert outcomes == {"passed": 1, "failed": 1, "skipped": 1, "xfailed": 1}
    assert "FAILED test_suite.py::test_file" in out
    assert "a shared_data test was skipped although the shared data must be there (CI is set" in out
    assert "absent.bin" in out


def test_required_without_the_folder_every_marked_test_fails(suite):
    outcomes, out = suite(False, T2M_REQUIRE_SHARED="1")
    assert outcomes == {"errors": 3, "skipped": 1}   # skipped at setup: pytest reports the failure as an error
    assert "(T2M_REQUIRE_SHARED=1): Skipped: shared folder not found at" in out


def test_require_shared_0_turns_the_check_off_in_ci(suite):
    outcomes, _ = suite(True, CI="true", T2M_REQUIRE_SHARED="0")
    assert outcomes == {"passed": 1, "skipped": 2, "xfailed": 1}


def test_shared_dir_honours_t2m_shared(monkeypatch, tmp_path):
    monkeypatch.setenv("T2M_SHARED", str(tmp_path))
    assert shared_dir() == tmp_path.resolve()
    monkeypatch.delenv("T2M_SHARED")
    assert shared_dir() == (REPO / ".." / "shared").resolve()
