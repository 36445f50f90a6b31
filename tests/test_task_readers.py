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
