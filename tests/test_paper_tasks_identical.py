"""The paper's tasks give the numbers they gave before tasks became data (issue #61), byte for
byte: a NEAT run (neat-python 0.92's genetics, the default) and a sep-CMA-ES run at a fixed seed
on red-green-red write the metrics.csv, species.csv and controllers stored in
tests/data/paper-tasks/, which the code before the change wrote (that folder's README says how),
and the step itself, eager and compiled, returns the stored bits (their SHA-256).

The arena's arithmetic is portable (envs/numerics.py), so the stored bytes hold on any x86-64
CPU; a difference means the step, a task's defaults or the loop computes something else."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import torch

from envs import TASKS, ForagingConfig, ForagingEnv
from lifelong_evo.commands.cli import main
from lifelong_evo.metrics import REFERENCE

STORED = Path(__file__).resolve().parent / "data" / "paper-tasks"
FLAGS = ["--preset", "smoke", "--generations", "3", "--env", "duration=60", "--seed", "42",
         "--schedule", "red-green-red", "--no-record", "--quiet"]
"""The runs' shared settings: the smoke preset (eager, one evaluation thread), cut to seconds."""
RUNS = {"neat-reg11": ["--algo", "neat", "--reg", "11"],
        "sep-cmaes-reg1": ["--algo", "sep-cmaes", "--reg", "1"]}
"""Stored run -> its own flags."""
STEP_DIGESTS = STORED / "step-sha256.json"
"""The SHA-256 of ``paper_step_bytes`` for each setting, written by the code before the change."""


def compared_files(run: Path) -> list[str]:
    """The files of a run directory the test compares, relative to it: metrics.csv, species.csv
    (NEAT's) and every controller but the regulariser's references, which task ends write since
    issue #62, after the stored runs were made (``tests/test_networks.py`` checks them)."""
    names = [name for name in ("metrics.csv", "species.csv") if (run / name).exists()]
    return names + sorted(f"controllers/{path.name}" for path in (run / "controllers").glob("*.json")
                          if not path.stem.endswith(f"-{REFERENCE}"))


@pytest.mark.parametrize("name", list(RUNS))
def test_paper_tasks_give_the_stored_bytes(name, tmp_path):
    assert main([*FLAGS, *RUNS[name], "--out", str(tmp_path), "--name", name]) == 0
    stored, fresh = STORED / name, tmp_path / name
    assert compared_files(fresh) == compared_files(stored), "the run wrote other files than the stored one"
    assert len(compared_files(stored)) >= 6
    for relative in compared_files(stored):
        assert (fresh / relative).read_bytes() == (stored / relative).read_bytes(), \
            f"{name}/{relative} differs from the stored bytes"


STATE_FIELDS = ("agent_pos", "heading", "carrying", "box_pos", "box_color", "box_present", "target", "season",
                "steps", "retrieved", "done", "respawn_key")
"""The ``ForagingState`` fields the paper's tasks had before #61 (the later ones are not hashed)."""


def paper_step_bytes(compiled: bool, steps: int = 300, batch: int = 32) -> tuple[bytes, int, int]:
    """Every output of the step and the state after it, as bytes, over ``steps`` steps of a batch
    of the paper's red and green tasks driven by wheel speeds held for 25 steps at a time, and
    the picks and drops on the way: the runs above see the step only through its events (a
    change that moves no event leaves their files as they were), this sees every bit of every float."""
    env = ForagingEnv(ForagingConfig(see_other_agents=True), batch_size=batch)
    if compiled:
        env.compile()
    generator = torch.Generator().manual_seed(61)
    out = [env.reset([TASKS["red"], TASKS["green"]] * (batch // 2), generator=7).numpy().tobytes()]
    picks = drops = 0
    for step in range(steps):
        if step % 25 == 0:
            held = torch.rand(batch, 1, 3, generator=generator) * 4 - 2
        wheels = held + torch.rand(batch, env.config.n_agents, 3, generator=generator) * 0.5
        observations, reward, done, info = env.step(wheels)
        out += [observations.numpy().tobytes(), reward.numpy().tobytes(), done.numpy().tobytes()]
        out += [info[key].numpy().tobytes() for key in sorted(info)]
        picks, drops = picks + int((info["picked"] >= 0).sum()), drops + int((info["dropped"] >= 0).sum())
        state = env.state
        out += [getattr(state, name).numpy().tobytes() for name in STATE_FIELDS]
    return b"".join(out), picks, drops


@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "compiled"])
def test_the_papers_step_gives_the_stored_bits(compiled):
    stepped, picks, drops = paper_step_bytes(compiled)
    assert picks >= 20 and drops >= 3, "the stored steps are not idle"
    assert hashlib.sha256(stepped).hexdigest() == json.loads(STEP_DIGESTS.read_text())["compiled" if compiled else "eager"]

