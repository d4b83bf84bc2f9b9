"""Where the tests find real data: the committed fixtures, and the project's shared folder for the few that need more.

- ``tests/fixtures/`` (always there, see its README for sources and licences): HumanML3D's sample clip 012314 (MIT)
  and 16 Bandai-Namco BVH clips (CC BY-NC 4.0) laid out like the unpacked archive. Almost every test on real motion
  uses these, so a fresh clone runs them.
- The shared folder (the whole Bandai-Namco archive, the CMU trials, ...): ``$T2M_SHARED``, else ``<repo>/../shared``.
  :func:`shared_dir` is the one place that says so. Only tests marked ``@pytest.mark.shared_data`` use it; they skip
  when it is absent, and :func:`require_shared` skips one of them (naming the path) when a file it needs is absent.

A skipped ``shared_data`` test must not hide in CI, where the data is meant to be there: the hooks below (imported by
tests/conftest.py) turn such a skip into a failure with CI=true (or 1) when the shared folder exists, and always with
T2M_REQUIRE_SHARED=1; T2M_REQUIRE_SHARED=0 turns that off.
"""
from __future__ import annotations

import os
from collections.abc import Generator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FIXTURES = REPO / "tests" / "fixtures"
HUMANML3D_SAMPLE = FIXTURES / "humanml3d-sample"          # new_joint_vecs/new_joints_012314.npy, Mean.npy, Std.npy
BANDAI_FIXTURE = FIXTURES / "bandai-namco" / "dataset"      # Bandai-Namco-Research-Motiondataset-{1,2}/...
MARKER = "shared_data"
_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def shared_dir() -> Path:
    """The project's shared folder: $T2M_SHARED, else ../shared beside the repository (it may not exist)."""
    configured = os.environ.get("T2M_SHARED")
    return Path(configured).resolve() if configured else (REPO.parent / "shared").resolve()


def require_shared(*parts: str) -> Path:
    """shared_dir() / parts, or a skip that names the path when it is absent (for tests marked shared_data)."""
    path = shared_dir().joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared data not found: {path} (set T2M_SHARED to the shared folder)")
    return path


def skips_must_fail() -> str | None:
    """Why a skipped shared_data test is a failure in this environment, or None where a skip is fine."""
    flag = os.environ.get("T2M_REQUIRE_SHARED", "").strip().lower()
    if flag in _FALSE:
        return None
    if flag in _TRUE:
        return "T2M_REQUIRE_SHARED=1"
    if os.environ.get("CI", "").strip().lower() in _TRUE and shared_dir().is_dir():
        return f"CI is set and the shared folder {shared_dir()} exists"
    return None


def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.get_closest_marker(MARKER) is not None and not shared_dir().is_dir():
        pytest.skip(f"shared folder not found at {shared_dir()} (set T2M_SHARED to the shared folder)")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, pytest.TestReport,
                                                                                             pytest.TestReport]:
    report = yield
    if report.skipped and not hasattr(report, "wasxfail") and item.get_closest_marker(MARKER) is not None:
        why = skips_must_fail()
        if why is not None:
            reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
            report.outcome = "failed"
            report.longrepr = (f"a shared_data test was skipped although the shared data must be there ({why}): "
                               f"{reason}")
    return report
