"""A pytest plugin for checks that a hard time limit may cut off: a failing test's report (its
traceback and the end of what it wrote to stderr, where a command's ``error:`` line goes) is
printed the moment it fails, not only in the summary at the end, which a killed session never
reaches. ``python -m pytest -p benchmarks.report_failures_at_once ...`` (the repository root on
the path), as ``benchmarks/gpu_checks.sh`` runs the GPU tests."""
import sys

STDERR_TAIL = 2000
"""Characters of each captured stderr section printed with a failure."""


def pytest_runtest_logreport(report):
    if report.failed:
        stderr = "".join(f"\n--- {name} (its end) ---\n{text[-STDERR_TAIL:]}" for name, text in report.sections
                         if "stderr" in name)
        print(f"\nFAILED {report.nodeid} ({report.when}):\n{report.longreprtext}{stderr}\n", file=sys.__stdout__,
              flush=True)
