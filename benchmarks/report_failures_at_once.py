"""A pytest plugin for checks that a hard time limit may cut off: a failing test's report is
printed the moment it fails, not only in the summary at the end, which a killed session never
reaches. ``python -m pytest -p benchmarks.report_failures_at_once ...`` (the repository root on
the path), as ``benchmarks/gpu_checks.sh`` runs the GPU tests."""
import sys


def pytest_runtest_logreport(report):
    if report.failed:
        print(f"\nFAILED {report.nodeid} ({report.when}):\n{report.longreprtext}\n", file=sys.__stdout__, flush=True)
