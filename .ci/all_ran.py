"""Exit 1, with one line saying which, unless a pytest JUnit XML report shows every given test file run, none skipped.

Usage: ``python .ci/all_ran.py REPORT.xml tests/test_a.py [tests/test_b.py ...]``. A test file counts as run when at
least one of its tests passed; any skipped test, or a test file skipped whole at collection (``importorskip``), fails.
"""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import PurePosixPath


def module_name(test_file: str) -> str:
    """``tests/test_a.py`` -> ``tests.test_a``, as pytest's JUnit report names its tests' classes."""
    return ".".join(PurePosixPath(test_file).with_suffix("").parts)


# A test case with one of these children did not pass
NOT_PASSED = ("skipped", "failure", "error")


def test_name(case: ET.Element) -> str:
    """``tests.test_a.test_x``; ``tests.test_a`` for a file skipped at collection (its class name is empty)."""
    return ".".join(part for part in (case.get("classname"), case.get("name")) if part)


def skip_reason(skip: ET.Element) -> str:
    """The reason pytest gave; for a collection skip, the reason out of its ``(path, line, reason)`` text."""
    message = skip.get("message", "")
    if message != "collection skipped":
        return message
    try:
        return str(ast.literal_eval(skip.text or "")[2])
    except (ValueError, SyntaxError, IndexError, TypeError):
        return (skip.text or message).strip()


def problems(report: str, test_files: list[str]) -> list[str]:
    """The given files' tests that the report shows skipped, and the given files none of whose tests passed."""
    cases = list(ET.parse(report).getroot().iter("testcase"))
    found = []
    for test_file in test_files:
        module = module_name(test_file)
        mine = [case for case in cases if test_name(case) == module or test_name(case).startswith(module + ".")]
        found += [f"{test_name(case)} ({skip_reason(skip)})" for case in mine for skip in case.iter("skipped")]
        if not any(all(case.find(outcome) is None for outcome in NOT_PASSED) for case in mine):
            found.append(f"{test_file} (no test of it passed)")
    return found


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print("usage: python .ci/all_ran.py REPORT.xml TEST_FILE [TEST_FILE ...]", file=sys.stderr)
        return 2
    found = problems(argv[0], argv[1:])
    if found:
        print(f"integration: these must run, not be skipped: {'; '.join(found)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
