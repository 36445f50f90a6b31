"""Everything that reads a run handles tasks defined as data (issue #61): ``replay --task NAME``,
``plot`` (a task's target colour, another line style for a second task of one colour),
``compare`` and the recording's nest outline."""
from __future__ import annotations

from pathlib import Path

import pytest

from envs import TASKS
from lifelong_evo.analysis import figures as plots
from lifelong_evo.commands.cli import main
from lifelong_evo.commands.replay import replay
from lifelong_evo.commands.rerun_recorder import drop_zone_outline
from lifelong_evo.errors import UserError
from lifelong_evo.runs import Run, load_runs
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


def _one_colour_run(names: list[str]) -> Run:
    """A run (in memory) whose schedule plays ``names``, every one a red task, 2 generations each,
    with retention of each earlier task measured."""
    tables = {name: {"target": "red", "season": ["red", "blue"]} for name in names if name not in TASKS}
    rows = []
    for index, name in enumerate(names):
        for generation in range(2 * index, 2 * index + 2):
            row = {"generation": str(generation), "task": name, "task_index": str(index), "best": "1", "top": "1"}
            rows.append(row | {f"retention_pop_{other}": "0.5" if k < index else "" for k, other in enumerate(names)})
    return Run(Path("one-colour"), {"schedule": ",".join(f"{name}:2" for name in names), "generations": 2,
                                    "tasks": tables}, {}, rows)


def test_tasks_of_one_colour_never_share_a_look(tmp_path, monkeypatch):
    """Six red tasks in one figure: each of the eleven curves (current per task, retention per task
    but the last) has a line style and marker no other has; a run with more red tasks than looks
    is refused."""
    drawn = []

    def band(ax, generations, values, color, linestyle, label, marker=None, markevery=None):
        drawn.append((label, linestyle, marker))
        return real_band(ax, generations, values, color, linestyle, label, marker, markevery)

    real_band = plots.band
    monkeypatch.setattr(plots, "band", band)
    names = ["red", "red-nest-bottom", "red-two-failed", "red-3", "red-4", "red-5"]
    assert plots.figure_retention([_one_colour_run(names)], "pop", tmp_path / "six.png", "six red tasks").exists()
    assert len(drawn) == 11 and len({tuple(look) for _, *look in drawn}) == 11, drawn
    assert drawn[0] == ("red: current C", "-", None)  # the first task of a colour: the paper's look
    too_many = _one_colour_run(["red", *(f"red-{i}" for i in range(len(plots.TASK_STYLES)))])
    with pytest.raises(UserError, match=f"{len(plots.TASK_STYLES) + 1} tasks of one target colour .* plot tells at most"):
        plots.check_task_looks(too_many)


def test_the_recording_draws_failed_robots_and_the_nest_where_the_task_puts_them(tmp_path):
    """An episode of a task with two failed robots and the nest at the bottom: in the recording
    robots 3 and 4 have the failed colour at every step, the working ones their carried box's
    colour, and the drop zone's outline lies along the bottom edge."""
    import dataclasses

    from lifelong_evo.commands.rerun_recorder import FAILED_RGB, RerunRecorder, _palette
    from tests.test_recording import read_rrd, rerun_chunk, small_episode

    episode = small_episode("red")
    carried = episode.carried_color.copy()
    carried[:, 0] = 3  # robot 0 carries a red box throughout
    episode = dataclasses.replace(episode, carried_color=carried, failed_robots=2, drop_zone="bottom")
    path = tmp_path / "episode.rrd"
    recorder = RerunRecorder(path, recording_id="failed", recording_name="failed", arena_size=20.0)
    recorder.log_episode_at("episodes/worn", episode, generation=1)
    recorder.close()

    def rgb(packed: int) -> tuple[int, int, int]:
        return packed >> 24, (packed >> 16) & 255, (packed >> 8) & 255

    agents = read_rrd(path)["episodes/worn/agents"]
    assert len(agents) == len(episode.agent_pos)
    palette = _palette()
    for row in agents:
        colors = [rgb(c) for c in row["Points2D:colors"]]
        assert colors[3:] == [tuple(FAILED_RGB)] * 2
        assert colors[0] == tuple(palette[3]) and colors[1] == colors[2] == tuple(palette[0])
        assert tuple(FAILED_RGB) not in colors[:3]
    outlines = [row for chunk in rerun_chunk.RrdReader(path).stream().to_chunks()
                if chunk.is_static and chunk.entity_path.lstrip("/") == "episodes/worn/drop_zone"
                for row in chunk.to_record_batch().to_pylist()]
    assert outlines[0]["LineStrips2D:strips"] == [[[0, 19], [20, 19], [20, 20], [0, 20], [0, 19]]]
    assert outlines[0]["LineStrips2D:labels"] == ["drop zone (bottom)"]
