"""Everything that reads a run handles tasks defined as data (issue #61): ``replay --task NAME``,
``plot`` (a task's target colour, another line style for a second task of one colour),
``compare`` and the recording's nest outline."""
from __future__ import annotations

from lifelong_evo.analysis import figures as plots
from lifelong_evo.commands.cli import main
from lifelong_evo.commands.replay import replay
from lifelong_evo.commands.rerun_recorder import drop_zone_outline
from lifelong_evo.runs import load_runs
from tests.test_task_files import SOUTH, TINY, task_file


def test_every_reader_handles_a_defined_task(tmp_path, capsys):
    runs = tmp_path / "runs"
    assert main([*TINY, "--tasks", task_file(tmp_path, SOUTH), "--schedule", "red:2,red-south:2",
                 "--out", str(runs), "--name", "south"]) == 0
    played, _ = replay(runs / "south", "red-south", episodes=2, record=False, quiet=True)
    assert len(played) == 2 and played[0].drop_zone == "bottom" and played[0].failed_robots == 1
    assert played[0].agent_pos[0, -1, 0] > 10, "the failed robot 4 starts by the bottom nest"
    assert (played[0].agent_pos[:, -1] == played[0].agent_pos[0, -1]).all(), "and never moves"
    run = load_runs([runs / "south"])[0]
    assert plots.task_color("red-south", run) == plots.task_color("red", run) == plots.task_color("red")
    assert plots.task_styles("red", run) != plots.task_styles("red-south", run)
    assert plots.plot_runs([runs / "south"], tmp_path / "figures")
    assert main(["compare", str(runs), "--out", str(tmp_path / "tables")]) == 0
    assert "red-south" in capsys.readouterr().out
    assert drop_zone_outline("top", 20.0).tolist() == [[0, 0], [20, 0], [20, 1], [0, 1], [0, 0]]
    assert drop_zone_outline("bottom", 20.0).tolist() == [[0, 19], [20, 19], [20, 20], [0, 20], [0, 19]]
    assert drop_zone_outline("left", 20.0).tolist() == [[0, 0], [1, 0], [1, 20], [0, 20], [0, 0]]
    assert drop_zone_outline("right", 20.0).tolist() == [[19, 0], [20, 0], [20, 20], [19, 20], [19, 0]]
