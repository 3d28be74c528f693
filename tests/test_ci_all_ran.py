"""CI's integration stage fails where its tests would be skipped: ``.ci/all_ran.py`` reads pytest's JUnit report and
exits 1, with one line naming them, on a skipped test, a test file skipped whole at collection, or a test file none
of whose tests passed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ALL_RAN = Path(__file__).resolve().parents[1] / ".ci" / "all_ran.py"

TEST_FILES = {
    "test_runs.py": "def test_one():\n    pass\n\n\ndef test_two():\n    pass\n",
    "test_skips_one.py": (
        "import pytest\n\n\ndef test_runs():\n    pass\n\n\n"
        "@pytest.mark.skipif(True, reason='Ray is not installed')\ndef test_on_ray():\n    pass\n"
    ),
    "test_skipped_whole.py": "import pytest\n\npytest.importorskip('no_such_driver')\n\n\ndef test_x():\n    pass\n",
    "test_fails.py": "def test_fails():\n    assert False\n",
}


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """pytest's JUnit report of a run of ``TEST_FILES`` (in ``tests/``), as the integration stage writes it."""
    root = tmp_path_factory.mktemp("suite")
    (root / "tests").mkdir()
    for name, text in TEST_FILES.items():
        (root / "tests" / name).write_text(text)
    (root / "pytest.ini").write_text("[pytest]\n")
    # Not the caller's options: CI's --basetemp would have this run clear the folder of the run that started it
    env = {name: value for name, value in os.environ.items() if name != "PYTEST_ADDOPTS"}
    junit = root / "report.xml"
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={junit}", "tests"]
    subprocess.run(command, cwd=root, env=env, capture_output=True, check=False, timeout=120)
    return junit


def all_ran(report: Path, *test_files: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(ALL_RAN), str(report), *test_files], capture_output=True, text=True, check=False
    )


def test_a_report_where_every_test_of_the_files_passed_is_accepted_silently(report: Path) -> None:
    result = all_ran(report, "tests/test_runs.py")
    assert (result.returncode, result.stdout, result.stderr) == (0, "", "")


def test_a_skipped_test_fails_with_one_line_naming_it_and_its_reason(report: Path) -> None:
    result = all_ran(report, "tests/test_runs.py", "tests/test_skips_one.py")
    assert result.returncode == 1
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("integration: ")
    assert "tests.test_skips_one.test_on_ray (Ray is not installed)" in result.stderr


def test_a_file_skipped_at_collection_or_failing_fails_naming_the_file(report: Path) -> None:
    result = all_ran(report, "tests/test_skipped_whole.py", "tests/test_fails.py", "tests/test_never_run.py")
    assert result.returncode == 1
    assert "no_such_driver" in result.stderr  # the collection skip's reason
    for test_file in ("tests/test_skipped_whole.py", "tests/test_fails.py", "tests/test_never_run.py"):
        assert f"{test_file} (no test of it passed)" in result.stderr
    assert "tests/test_runs.py" not in result.stderr
