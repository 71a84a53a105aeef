#!/usr/bin/python3
"""Reads the JUnit XML `tofu check scenarios/` wrote (ctest scenario_check) and checks its
shape: one <testsuite> per scenario file, each with the run's testcase and at least one
expectation testcase, counts that add up, and no failure or error.

    tests/junit_check.py JUNIT_XML EXPECTED_SUITES
"""
import sys
import xml.etree.ElementTree as ET


def main():
    path, expected_suites = sys.argv[1], int(sys.argv[2])
    root = ET.parse(path).getroot()
    problems = []
    if root.tag != "testsuites":
        problems.append(f"root element is <{root.tag}>, expected <testsuites>")
    suites = root.findall("testsuite")
    if len(suites) != expected_suites:
        problems.append(f"{len(suites)} test suites, expected one per scenario ({expected_suites})")
    total = 0
    for suite in suites:
        cases = suite.findall("testcase")
        total += len(cases)
        name = suite.get("name")
        if int(suite.get("tests", -1)) != len(cases):
            problems.append(f"{name}: tests={suite.get('tests')} but {len(cases)} <testcase>")
        if not any(c.get("name") == "run" for c in cases):
            problems.append(f"{name}: no 'run' testcase")
        if len(cases) < 2:
            problems.append(f"{name}: no expectation testcase")
        for case in cases:
            for bad in case.findall("failure") + case.findall("error"):
                problems.append(f"{name}/{case.get('name')}: {bad.get('message')}")
    if int(root.get("tests", -1)) != total:
        problems.append(f"testsuites tests={root.get('tests')} but {total} testcases")
    for p in problems:
        print(f"{path}: {p}", file=sys.stderr)
    print(f"{path}: {len(suites)} suites, {total} testcases, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
