"""The Rerun recording read back (rerun.chunk.RrdReader) against metrics.csv and replayed
episodes; ``view`` argument handling; ``replay``."""
from __future__ import annotations

import json
import os
import random
import shutil
import socket
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from lifelong_evo.commands.cli import main as cli_main

rerun_chunk = pytest.importorskip("rerun.chunk")


def read_rrd(path: Path) -> dict[str, list[dict]]:
    """Entity path (without the leading /) -> temporal rows (dicts of the record batch)."""
    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in rerun_chunk.RrdReader(path).stream().to_chunks():
        if chunk.is_static:
            continue
        rows[chunk.entity_path.lstrip("/")].extend(chunk.to_record_batch().to_pylist())
    return rows


def scalar_series(rows: dict[str, list[dict]], entity: str, gaps: bool = False) -> dict[int, float]:
    """generation -> value of a curve; the NaN points that break lines at drifts only with ``gaps``."""
    series = {row["generation"]: row["Scalars:scalars"][0] for row in rows.get(entity, [])}
    return {g: v for g, v in series.items() if gaps == np.isnan(v)}


TINY = ["--generations", "3", "--env", "duration=60"]
"""The smoke preset cut to its old size: these tests check recordings, not learning."""


@pytest.fixture(scope="module")
def neat_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    assert cli_main(["--algo", "neat", "--reg", "1", "--preset", "smoke", *TINY, "--out", str(out), "--name", "r",
                     "--quiet"]) == 0
    return out / "r"


@pytest.fixture(scope="module")
def es_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    assert cli_main(["--algo", "openai-es", "--preset", "smoke", *TINY, "--out", str(out), "--name", "e",
                     "--quiet"]) == 0
    return out / "e"


def check_scalars_equal_metrics(run: Path, rows: dict[str, list[dict]]) -> int:
    """Every curve point equals metrics.csv, and nothing else was logged; returns points checked."""
    from lifelong_evo.metrics_csv import read_metrics

    metrics = read_metrics(run / "metrics.csv")
    expected: dict[str, dict[int, float]] = defaultdict(dict)
    for row in metrics:
        g, task = int(row["generation"]), row["task"]
        for key, entity in (("best", f"curves/current/{task}/best"), ("mean", f"curves/current/{task}/mean"),
                            ("reg_best", f"curves/regularised/{task}/best"),
                            ("reg_mean", f"curves/regularised/{task}/mean"), ("top", f"curves/current/{task}/top"),
                            ("species", "curves/species"), ("centre", f"curves/centre/{task}")):
            if row.get(key):
                expected[entity][g] = float(row[key])
        for key, value in row.items():
            for level in ("pop", "top", "centre"):
                if key.startswith(f"retention_{level}_") and value:
                    expected[f"curves/retention_{level}/{key[len(f'retention_{level}_'):]}"][g] = float(value)
    logged = {e for e in rows if e.startswith("curves/") and not e.startswith("curves/extra/")}
    assert logged == set(expected), (sorted(logged ^ set(expected)))
    drifts = {int(b["generation"]) for a, b in zip(metrics, metrics[1:]) if a["task_index"] != b["task_index"]}
    checked = 0
    for entity, points in expected.items():
        assert scalar_series(rows, entity) == pytest.approx(points), entity
        assert set(scalar_series(rows, entity, gaps=True)) <= drifts, entity
        checked += len(points)
    current = [e for e in expected if e.startswith("curves/current/red/")]
    assert all(set(scalar_series(rows, e, gaps=True)) == {3} for e in current)  # red pauses at 3
    assert any(e.startswith("curves/retention_pop/") for e in expected), "no retention measured"
    return checked


def check_episodes(run: Path, rows: dict[str, list[dict]]) -> None:
    """The episodes the recorder logged are those of the stored task-end controllers, replayed
    with the loop's seeds: same agent positions, box counts, cumulative reward."""
    from algorithms import policy_from_export
    from envs import TASKS
    from lifelong_evo.commands.rerun_recorder import expected_episode_paths
    from lifelong_evo.episodes import play_episodes
    from lifelong_evo.rundir import RunDir

    config = RunDir(run).read_config()
    env = config.env_config()
    expected = [path for path, _ in expected_episode_paths(config)]
    logged = sorted({e.rsplit("/", 1)[0] for e in rows if e.startswith("episodes/")})
    assert logged == sorted(expected)
    assert len(expected) == 5  # red-green-red: 1 + 2 + 2 tasks seen at the three task ends
    phases = config.phases()
    for path in expected:
        head, on = path.split("/")[1:]
        generation, phase_task = int(head[3:7]), head[8:]
        phase_index = next(i for i, _ in enumerate(phases) if sum(p.generations for p in phases[:i + 1]) - 1
                           == generation)
        exported = json.loads((run / "controllers" / f"task{phase_index}-{phase_task}-top.json").read_text())
        episode = play_episodes(policy_from_export(exported), env, TASKS[on[3:]],
                                [config.seed * 1_000_003 + generation])[0]
        steps = len(episode.agent_pos)
        agents = rows[f"{path}/agents"]
        assert [r["step"] for r in agents] == list(range(steps))
        assert all(r["generation"] == generation for r in agents)
        assert all(len(r["Points2D:positions"]) == env.n_agents for r in agents)
        positions = np.array([r["Points2D:positions"] for r in agents])
        np.testing.assert_allclose(positions, episode.agent_pos[..., ::-1], atol=1e-5)  # screen = (y, x)
        trails = rows[f"{path}/trails"]
        assert all(len(r["LineStrips2D:strips"]) == env.n_agents for r in trails)
        assert [len(s) for s in trails[-1]["LineStrips2D:strips"]] == [min(steps, 20)] * env.n_agents
        boxes = rows[f"{path}/boxes"]
        assert boxes[0]["step"] == 0
        for r in boxes:
            assert len(r["Points2D:positions"]) == int(episode.box_present[r["step"]].sum())
        assert len(boxes[0]["Points2D:positions"]) == env.n_boxes
        reward = rows[f"{path}/reward"]
        assert len(reward) == steps
        assert reward[-1]["Scalars:scalars"][0] == pytest.approx(episode.total_reward)


def test_recording_matches_metrics_and_episodes(neat_run):
    path = neat_run / "recording.rrd"
    assert path.is_file()
    assert path.stat().st_size < 2_000_000, "a smoke recording should be a few hundred kB"
    reader = rerun_chunk.RrdReader(path)
    assert reader.recordings() and reader.blueprints(), "the recording and its default blueprint"
    entry = reader.recordings()[0]
    assert (entry.application_id, entry.recording_id) == ("lifelong_evo", "lifelong_evo/r")
    rows = read_rrd(path)
    assert check_scalars_equal_metrics(neat_run, rows) > 30
    assert "curves/species" in rows
    texts = [r["TextLog:text"][0] for r in sorted(rows["log"], key=lambda r: r["generation"])]
    drifts = [text for text in texts if "drift" in text]
    assert len(drifts) == 2 and "red -> green" in drifts[0]
    check_episodes(neat_run, rows)


def test_es_recording_and_resume_writes_a_second_part(es_run, tmp_path):
    rows = read_rrd(es_run / "recording.rrd")
    check_scalars_equal_metrics(es_run, rows)
    assert "curves/centre/red" in rows and any(e.startswith("curves/extra/") for e in rows)
    check_episodes(es_run, rows)
    # resume from the checkpoint before the last generation: a second file, the first kept as it was
    run = tmp_path / "e"
    shutil.copytree(es_run, run)
    first = (run / "recording.rrd").read_bytes()
    checkpoints = sorted((run / "checkpoints").glob("generation-*.pt"))
    checkpoints[-1].unlink()
    generation = int(checkpoints[-2].stem.split("-")[1])
    assert cli_main(["--resume", "--out", str(tmp_path), "--name", "e", "--quiet"]) == 0
    assert (run / "recording.rrd").read_bytes() == first
    second = run / f"recording-resumed-{generation:06d}.rrd"
    assert second.is_file()
    resumed = read_rrd(second)
    assert {g for e, r in resumed.items() if e.startswith("curves/current/") for g in scalar_series(resumed, e)} \
        == set(range(generation, 9))
    from lifelong_evo.commands.view import recording_files

    assert recording_files(run) == [run / "recording.rrd", second]


def test_paper_scale_recording_stays_small(tmp_path):
    """600 generations and episodes of 500 steps at three task ends (the paper's run; 1, 2, 2
    tasks), logged through the recorder: far below 50 MB."""
    from envs import TASKS
    from lifelong_evo.commands.rerun_recorder import RerunRecorder, expected_episode_paths, make_blueprint
    from lifelong_evo.config import resolve
    from lifelong_evo.episodes import Episode
    from lifelong_evo.metrics import FitnessStats, GenerationRecord, Retention

    config = resolve("paper", {}, {"algo": "neat"})
    path = tmp_path / "big.rrd"
    recorder = RerunRecorder(path, recording_id="big", recording_name="big", arena_size=20.0,
                             blueprint=make_blueprint(expected_episode_paths(config)))
    rng = np.random.default_rng(0)
    names = ["red", "green", "red"]
    for g in range(600):
        phase = g // 200
        retention = {names[phase - 1]: Retention(pop=rng.random(), top=rng.random())} if phase and g % 10 == 0 else {}
        recorder.log_generation(GenerationRecord(
            task=names[phase], task_index=phase, generation=g, generation_in_task=g % 200,
            fitness=FitnessStats(best=rng.random(), mean=rng.random(), median=0.0, std=0.0),
            regularised=FitnessStats(best=rng.random(), mean=rng.random(), median=0.0, std=0.0), top=rng.random(),
            retention=retention, species_sizes={1: 300}))
        if g % 200 == 199:
            for task in dict.fromkeys(names[:phase + 1]):
                T, A, K = 501, 5, 20
                positions = np.cumsum(rng.normal(0, 0.1, (T, A, 2)), axis=0) + 10
                present = np.ones((T, K), bool)
                present[rng.integers(0, T, 30), rng.integers(0, K, 30)] = False
                recorder.log_episode(g, phase, names[phase], TASKS[task], Episode(
                    task=task, target=TASKS[task].target, agent_pos=positions,
                    carried_color=rng.choice([0, 3, 4], (T, A)), box_pos=rng.integers(2, 18, (T, K, 2)) * 1.0,
                    box_present=present, box_color=rng.choice([3, 4], K), rewards=rng.integers(-1, 3, T - 1) * 1.0))
    recorder.close()
    size = path.stat().st_size
    assert size < 15_000_000, f"{size / 1e6:.1f} MB"
    rows = read_rrd(path)
    assert len(scalar_series(rows, "curves/current/red/best")) == 400
    assert sum(len(r) for e, r in rows.items() if e.endswith("/agents")) == 5 * 501


def test_replay_prints_and_records(es_run, capsys):
    assert cli_main(["replay", str(es_run), "--episodes", "2", "--controller", "task1", "--task", "green"]) == 0
    out = capsys.readouterr().out
    assert "episode 0 (seed 1000000): reward" in out and "episode 1 (seed 1000001)" in out
    assert "mean reward of task1-green-top.json on green over 2 episodes" in out
    path = es_run / "replay-task1-green.rrd"
    rows = read_rrd(path)
    agents = rows["replay/task1/on_green/episode1/agents"]
    assert len(agents) == 61 and all(len(r["Points2D:positions"]) == 5 for r in agents)
    # the default: the final controller on the run's last task
    assert cli_main(["replay", str(es_run), "--episodes", "1", "--no-record"]) == 0
    assert "final-top.json on red over 1 episodes" in capsys.readouterr().out
    assert not (es_run / "replay-red.rrd").exists()


@pytest.mark.parametrize("argv, message", [
    (["--task", "blue"], "unknown task 'blue': choose one of red, green, purple, cyan"),
    (["--controller", "task7"], "no controller 'task7'"),
    (["--controller", "../config"], "no controller '../config'"),  # a name, not a way out of controllers/
    (["--episodes", "0"], "argument --episodes: '0' is not an integer from 1 to 10000"),
    (["--episodes", str(10**11)], "argument --episodes: '100000000000' is not an integer from 1 to 10000"),
    (["--seed", str(10**23)], "argument --seed: '100000000000000000000000' is not an integer from 0 to "),
])
def test_replay_errors_are_one_line(es_run, capsys, argv, message):
    assert cli_main(["replay", str(es_run), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_replay_of_a_missing_run(tmp_path, capsys):
    assert cli_main(["replay", str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_view_arguments_and_errors(es_run, tmp_path, capsys, monkeypatch):
    from lifelong_evo.commands import view

    calls = []

    class Viewer:
        def __init__(self, command, **kwargs):
            calls.append(command)

        def wait(self):
            return 0

        def poll(self):
            return 0

    monkeypatch.setattr(view.subprocess, "Popen", Viewer)
    monkeypatch.setattr(view, "port_in_use", lambda port: False)  # other programs may hold 9876 here
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert cli_main(["view", str(es_run), "--port", "9191"]) == 0  # no display: the web viewer
    command = calls[-1]
    assert command[1:6] == ["--web-viewer", "--bind", "127.0.0.1", "--web-viewer-port", "9191"]
    assert command[-1] == str(es_run / "recording.rrd")
    assert "web viewer: http://127.0.0.1:9191/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy" \
        in capsys.readouterr().out
    monkeypatch.setenv("DISPLAY", ":0")
    assert cli_main(["view", str(es_run / "recording.rrd")]) == 0  # a display: the native viewer
    assert calls[-1][1:] == [str(es_run / "recording.rrd")]
    assert cli_main(["view", str(es_run), "--web"]) == 0
    assert "--web-viewer" in calls[-1]
    # errors: one line, no viewer started
    calls.clear()
    empty = tmp_path / "norecord"
    empty.mkdir()
    (empty / "config.json").write_text("{}")
    for target, message in ((empty, "has no recording.rrd"), (tmp_path / "missing", "does not exist"),
                            (empty / "config.json", "is not an .rrd file")):
        assert cli_main(["view", str(target)]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1
    assert calls == []


def test_view_refuses_what_rerun_cannot_read_before_starting_a_viewer(es_run, tmp_path, capsys, monkeypatch):
    """A file of random bytes named .rrd started the viewer, and so did one that only begins as a
    recording (the FourCC, then noise); a recording cut short by a killed run still opens (the
    viewer reads it up to the break)."""
    from lifelong_evo.commands import view

    started = []
    monkeypatch.setattr(view.subprocess, "Popen", lambda command, **kwargs: started.append(command))
    noise = tmp_path / "noise.rrd"
    noise.write_bytes(random.Random(0).randbytes(4096))
    empty = tmp_path / "empty.rrd"
    empty.write_bytes(b"")
    fourcc = tmp_path / "fourcc.rrd"
    fourcc.write_bytes(b"RRF2" + random.Random(1).randbytes(4096))
    header = tmp_path / "header.rrd"  # a real recording's stream header, then noise
    header.write_bytes((es_run / "recording.rrd").read_bytes()[:12] + bytes(16) + random.Random(2).randbytes(4096))
    run = tmp_path / "run"
    shutil.copytree(es_run, run)
    (run / "recording-resumed-9.rrd").write_bytes(noise.read_bytes())  # a damaged part of a run's recording
    for target, reason in ((noise, 'Not an RRD file: expected FourCC header "RRF2"'),
                           (empty, "file too small to be an RRD"), (fourcc, ""), (header, ""),
                           (run, "recording-resumed-9.rrd")):
        assert cli_main(["view", str(target), "--web"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and "is not a recording Rerun can read" in err and reason in err, err
        assert err.count("\n") == 1
    assert started == []
    whole = (es_run / "recording.rrd").read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(whole[:len(whole) // 2])
    view.check_recording(cut)  # opens: Rerun reads it up to the break
    view.check_recording(es_run / "recording.rrd")


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _view(*args: str, **kwargs) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])
    return subprocess.Popen([sys.executable, "-m", "lifelong_evo", "view", *args], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kwargs)


def test_view_refuses_a_port_in_use_before_printing_an_address(es_run, capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        for flags in (["--port", str(port)], ["--grpc-port", str(port)]):
            assert cli_main(["view", str(es_run), "--web", *flags]) == 2
            captured = capsys.readouterr()
            assert "http" not in captured.out, "no address is printed for a viewer that cannot start"
            assert captured.err.startswith(f"error: port {port} on 127.0.0.1 is in use") and \
                captured.err.count("\n") == 1 and flags[0] in captured.err


def _alive(pid: int) -> bool:
    """Running: neither gone nor a zombie waiting to be reaped."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _wait_for(condition, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the kernel's parent-death signal is Linux's")
def test_killed_view_takes_its_viewer_along(es_run):
    """SIGKILL leaves ``view`` no chance to stop the viewer: the viewer must go by itself and free
    the ports, so that the next ``view`` serves its own recording there. Rerun's log stays out of
    the output without --verbose."""
    from lifelong_evo.commands.view import port_in_use

    port, grpc_port = _free_port(), _free_port()
    parent = _view(str(es_run), "--web", "--port", str(port), "--grpc-port", str(grpc_port))
    try:
        printed = parent.stdout.readline() + parent.stdout.readline()
        assert f"web viewer: http://127.0.0.1:{port}/" in printed
        assert _wait_for(lambda: port_in_use(port) and port_in_use(grpc_port), 30), "the viewer did not start"
        children = Path(f"/proc/{parent.pid}/task/{parent.pid}/children").read_text().split()
        assert len(children) == 1
    finally:
        parent.kill()
        parent.wait()
    assert _wait_for(lambda: not _alive(int(children[0])), 10), "the viewer outlived view"
    assert _wait_for(lambda: not port_in_use(port) and not port_in_use(grpc_port), 10), "the ports stay taken"
    assert "INFO" not in parent.stderr.read(), "rerun's log lines are shown only with --verbose"


def test_a_failing_viewer_is_one_line(es_run, tmp_path, monkeypatch):
    fake = tmp_path / "rerun"
    fake.write_text("#!/bin/sh\nprintf '\\033[32m INFO\\033[0m starting\\n' >&2\n"
                    "printf '\\033[33m WARN\\033[0m no GPU adapter found\\n' >&2\nexit 3\n")
    fake.chmod(0o755)
    port, grpc_port = _free_port(), _free_port()
    monkeypatch.setenv("RERUN_CLI_PATH", str(fake))
    quiet = _view(str(es_run), "--web", "--port", str(port), "--grpc-port", str(grpc_port))
    out, err = quiet.communicate(timeout=60)
    assert quiet.returncode == 2
    assert err == "error: the rerun viewer stopped with exit code 3: WARN no GPU adapter found " \
                  "(run again with --verbose for its whole log)\n"
    verbose = _view(str(es_run), "--web", "--port", str(port), "--grpc-port", str(grpc_port), "--verbose")
    out, err = verbose.communicate(timeout=60)
    assert verbose.returncode == 3 and "starting" in err and "no GPU adapter found" in err


def small_episode(task: str, steps: int = 6, agents: int = 5, boxes: int = 4):
    from envs import TASKS
    from lifelong_evo.episodes import Episode

    rng = np.random.default_rng(1)
    present = np.ones((steps, boxes), bool)
    present[3:, 0] = False  # box 0 picked up at step 3
    return Episode(task=task, target=TASKS[task].target, agent_pos=rng.random((steps, agents, 2)) * 20,
                   carried_color=np.zeros((steps, agents), int), box_pos=np.full((steps, boxes, 2), 5.0),
                   box_present=present, box_color=np.array([3, 4, 3, 4]), rewards=np.ones(steps - 1))


def test_episodes_off_the_schedule_update_the_blueprint(tmp_path, monkeypatch):
    from envs import TASKS
    from lifelong_evo.commands.rerun_recorder import RerunRecorder
    from lifelong_evo.config import resolve
    from lifelong_evo.rundir import RunDir

    monkeypatch.delenv("LIFELONG_EVO_RERUN", raising=False)
    run_dir = RunDir(tmp_path / "run")
    config = resolve("smoke", overrides={"generations": 3})  # generation 2 ends the first task
    recorder = RerunRecorder.for_run(run_dir, config, resume=False)
    assert not run_dir.path.exists(), "nothing is written before the loop creates the run directory"
    recorder.log_episode(2, 0, "red", TASKS["red"], small_episode("red"))  # a task end: in the blueprint
    recorder.close()
    assert len(rerun_chunk.RrdReader(run_dir.recording).blueprints()) == 1
    recorder = RerunRecorder.for_run(run_dir, config, resume=False)
    recorder.log_episode(1, 0, "red", TASKS["red"], small_episode("red"))  # not a task end
    recorder.close()
    assert len(rerun_chunk.RrdReader(run_dir.recording).blueprints()) == 2
    rows = read_rrd(run_dir.recording)
    boxes = rows["episodes/gen0001_red/on_red/boxes"]
    assert [(r["step"], len(r["Points2D:positions"])) for r in boxes] == [(0, 4), (3, 3)]  # logged on change


def test_unknown_sink_mode_is_one_line_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("LIFELONG_EVO_RERUN", "bogus")
    assert cli_main(["--preset", "smoke", "--out", str(tmp_path), "--name", "x", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "LIFELONG_EVO_RERUN='bogus' is not one of file, connect, both" in err and err.count("\n") == 1


def test_episodes_every_records_the_top_individual_between_task_ends(tmp_path):
    assert cli_main(["--algo", "openai-es", "--preset", "smoke", *TINY, "--episodes-every", "4", "--out", str(tmp_path),
                 "--name", "p", "--quiet"]) == 0
    rows = read_rrd(tmp_path / "p/recording.rrd")
    periodic = sorted({path.split("/")[1] for path in rows if path.startswith("episodes/")})
    # generations 0, 4 and 8 by the interval, 2, 5 and 8 as task ends (red, green, red)
    assert periodic == ["gen0000_red", "gen0002_red", "gen0004_green", "gen0005_green", "gen0008_red"]
    assert len(rows["episodes/gen0004_green/on_red/agents"]) > 1
    assert len(rows["episodes/gen0004_green/on_green/agents"]) > 1
