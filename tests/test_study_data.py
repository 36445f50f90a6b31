"""What docs/results.md says of the deciding study's data, checked on the data kept in
docs/data/study: each run's training numbers repeat the earlier run of its configuration and
seed byte for byte where one exists (the reproducibility check of its plan), and each run keeps
what the held-out protocol needs (its controllers and its held-out block)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[1] / "docs/data"
EARLIER = {"paper-claim": DATA / "paper-genetics"}
"""Each part of the study -> the earlier study whose runs of the same name it repeats."""
RUNS = sorted(path for path in (DATA / "study").glob("*/*") if (path / "metrics.csv").is_file())


def test_the_study_has_data():
    assert RUNS, "docs/data/study holds no run"


@pytest.mark.parametrize("run", RUNS, ids=lambda path: f"{path.parent.name}/{path.name}")
def test_a_study_run_repeats_its_earlier_run_and_keeps_its_controllers(run):
    earlier = EARLIER.get(run.parent.name, DATA / "none") / run.name
    if earlier.is_dir():
        assert (run / "metrics.csv").read_bytes() == (earlier / "metrics.csv").read_bytes()
    summary = json.loads((run / "summary.json").read_text())
    assert len(summary["phases"]) == 3 and summary["held_out"]["episodes"] == 100
    kept = {path.stem for path in (run / "controllers").glob("*.json")}
    assert {key for key in summary["held_out"]["scores"]} <= kept
