"""What docs/studies/regularisers-and-archive.md says of step 2's data, checked on the runs kept in
docs/data/regularisers-and-archive: each is its trial of examples/sweep_regularisers.toml (or, for
a fine-tune or rehearsal partner made again by a note of the page, of examples/sweep_baselines.toml),
keeps what the held-out protocol needs, ran under the native arithmetic on the kind of CPU the plan
and its notes give its family and seed, and (the plan's check) repeats its fine-tune partner's
training columns byte for byte up to where what it adds first acts: the first drift (generation
199), or for an archive run red's return (generation 399); and that the page's row of Q3's second
test is its snippet's result on the kept runs."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from lifelong_evo.analysis.comparison import comparison, format_difference
from lifelong_evo.analysis.statistics import welch_difference
from lifelong_evo.commands.cli import build_parser
from lifelong_evo.commands.grid import build_grid
from lifelong_evo.rundir import RunDir
from tests.run_data import assert_keeps_what_held_out_scoring_needs

ROOT = Path(__file__).resolve().parents[1]
KEPT = sorted(path for path in (ROOT / "docs/data/regularisers-and-archive").glob("*")
              if (path / "metrics.csv").is_file())
AMD_ZEN4 = {"cpu": "AMD EPYC (family 25, model 17)", "vector_isa": "AVX512"}
INTEL = {"cpu": "Intel(R) Xeon(R) Processor (family 6, model 167)", "vector_isa": "AVX512"}
ON_AMD_ZEN4 = {("neat", 17), ("neat", 24), ("neat", 31), ("sep-cmaes", 24), ("sep-cmaes", 42)}
"""The families and seeds whose reused baseline rows were made on the AMD Zen 4 kind (the plan,
"Arithmetic and machines"); every other one's on the Intel kind."""
REMADE_PARTNERS = {"sep-cmaes-reg0-seed24", "sep-cmaes-rehearsal0.3-seed24"}
"""Fresh fine-tune and rehearsal partners made on the Intel kind for a family and seed made whole
there, kept beside the new rows (the note of 2026-12-05, 04:13 UTC)."""
TRAINING_COLUMNS = ("task", "generation", "best", "mean", "median", "std", "top", "species", "disabled_fraction")
"""metrics.csv's columns that the fine-tune run has too and that no regulariser writes."""


def _trials(sweep_file: str) -> dict:
    args = build_parser().parse_args(["sweep", "--config", str(ROOT / "examples" / sweep_file)])
    return {trial.name: trial for trial in build_grid(args).trials}


TRIALS = _trials("sweep_regularisers.toml")
PARTNER_TRIALS = {name: trial for name, trial in _trials("sweep_baselines.toml").items() if name in REMADE_PARTNERS}


def test_the_sweep_is_the_plans():
    assert len(TRIALS) == 25 and {run.name for run in KEPT} <= TRIALS.keys() | PARTNER_TRIALS.keys()
    assert PARTNER_TRIALS.keys() == REMADE_PARTNERS


def _fine_tune_partner(algo: str, seed: int) -> Path:
    """The fine-tune run this family and seed's new rows pair with: one made again for them, kept
    beside them; else the baselines page's, its own baselines run or, for sep-CMA-ES seeds 13, 17
    and 31, the families study's lambda-0 run it reuses."""
    for folder in (f"regularisers-and-archive/{algo}-reg0-seed{seed}", f"baselines/{algo}-reg0-seed{seed}"):
        if (ROOT / "docs/data" / folder).is_dir():
            return ROOT / "docs/data" / folder
    return ROOT / "docs/data/study/families" / f"reg0-seed{seed}"


def _planned_kind(algo: str, seed: int) -> dict:
    """Intel where the seed's partners were made again (kept beside the new rows), else the kind of
    its reused baseline rows."""
    if _fine_tune_partner(algo, seed).parent.name == "regularisers-and-archive":
        return INTEL
    return AMD_ZEN4 if (algo, seed) in ON_AMD_ZEN4 else INTEL


@pytest.mark.parametrize("run", KEPT, ids=lambda path: path.name)
def test_a_kept_run_is_its_trial_on_its_kind_of_cpu(run):
    trial = TRIALS.get(run.name) or PARTNER_TRIALS[run.name]
    assert RunDir(run).setting_differences(trial.config.to_dict()) == []
    assert_keeps_what_held_out_scoring_needs(run)
    config, summary = (json.loads((run / name).read_text()) for name in ("config.json", "summary.json"))
    planned = _planned_kind(config["algo"], config["seed"])
    assert config["numerics"] == summary["numerics"] == "native"
    assert summary["machines"] and all({key: m[key] for key in planned} == planned for m in summary["machines"])


def _columns(path: Path, last_generation: int) -> list[tuple[str, ...]]:
    with open(path, newline="") as handle:
        return [tuple(row.get(name, "") for name in TRAINING_COLUMNS) for row in csv.DictReader(handle)
                if int(row["generation"]) <= last_generation]


@pytest.mark.parametrize("run", KEPT, ids=lambda path: path.name)
def test_a_kept_run_repeats_its_fine_tune_partner_until_what_it_adds_acts(run):
    config = json.loads((run / "config.json").read_text())
    partner = _fine_tune_partner(config["algo"], config["seed"])
    partner_config = json.loads((partner / "config.json").read_text())
    assert [partner_config[key] for key in ("algo", "seed", "reg")] == [config["algo"], config["seed"], 0]
    last = 399 if config.get("archive") else 199
    mine = _columns(run / "metrics.csv", last)
    assert len(mine) == last + 1 and mine == _columns(partner / "metrics.csv", last)


Q3_ROW = "| red F_top: NEAT's paired difference from its fine-tune minus sep-CMA-ES's | held-out | {} |"
"""The study page's row of Q3's second test (the note of 2026-12-04, 22:30 UTC, run as its snippet)."""


def test_the_pages_q3_welch_row_is_the_snippets_result_on_the_kept_runs():
    functional = {run.name: run for run in KEPT if "-functional-" in run.name}
    assert sorted(functional) == sorted(name for name in TRIALS if "-functional-" in name)  # all ten
    partners = [_fine_tune_partner(*(json.loads((run / "config.json").read_text())[key] for key in ("algo", "seed")))
                for run in functional.values()]
    rows = comparison([*functional.values(), *partners]).rows
    effect = {row["configuration"]: row["values"] for row in rows if row["statistic"] == "paired difference"
              and row["episodes"] == "held-out" and row["metric"] == "F_top red at end of phase 1"}
    result = welch_difference(effect["neat reg=1 red-green-red regulariser=functional"],
                              effect["sep-cmaes reg=10 red-green-red regulariser=functional"])
    page = (ROOT / "docs/studies/regularisers-and-archive.md").read_text()
    assert Q3_ROW.format(" | ".join(format_difference(result))) in page
