"""The Rerun recording of a run (rerun-sdk 0.41): ``runs/<name>/recording.rrd``.

What is recorded (application id ``lifelong_evo``, recording id ``lifelong_evo/<run name>``):

``generation`` timeline, one row per generation (series coloured by task colour):
  ``curves/current/<task>/best`` and ``.../mean``      raw fitness of the current task
  ``curves/regularised/<task>/best`` and ``.../mean``  after the regulariser
  ``curves/retention_pop/<task>``, ``curves/retention_top/<task>``, ``curves/retention_centre/<task>``
                                                       earlier tasks, where measured
  ``curves/centre/<task>``                             an ES's centre on the current task
  ``curves/species``                                   NEAT's species count
  ``curves/extra/<name>``                              the optimiser's extra scalars (e.g. ES sigma)
  ``log``                                              a text entry at each drift and task end
  ``network/graph``, ``network/summary``               at each task end, the top individual's network
                                                       against the reference written beside it
                                                       (``lifelong_evo.networks``; as ``plot`` draws it):
                                                       NEAT's nodes and enabled connections (a graph
                                                       view; the weights as ``weight`` values beside
                                                       the edges, connections the reference lacks as
                                                       ``new``); an MLP's layer sizes and per-layer
                                                       distance (``network/layer_distance``, a bar
                                                       chart); the summary as markdown: what was
                                                       measured, the regulariser, every weight or
                                                       distance. The latest task end shows.
  (a NaN point at a drift ends the line of each series that pauses there)
``step`` timeline, episodes of each task end's top individual on every task seen so far, under
``episodes/gen<G>_<phase task>/on_<task>/``: ``arena`` and ``drop_zone`` (static outlines; the
drop zone along the task's nest edge), ``boxes`` (present boxes in their colour, logged at the
steps where they change), ``agents`` (coloured by the box they carry, grey when empty, brown when
the task failed them), ``trails`` (each agent's last 20 positions) and ``reward`` (cumulative).
These rows also carry the ``generation`` index, so the generation timeline shows each episode's
last frame. Screen coordinates are (y, x): x is the vertical axis and x = 0, the paper's drop
zone, is the top edge (a 2D view's y axis points down). A task's curves have its target colour.
Episodes are sent column-wise (``send_columns``, one call per entity), which keeps the file
small.

A default blueprint comes with the recording: the curves on the left, the arena (one tab per
episode) on the right, the text log below.

Resume: rerun 0.41 cannot append to an .rrd file, so ``--resume`` writes the continuation to
``recording-resumed-<generation>.rrd`` beside ``recording.rrd`` (<generation> = the checkpoint it
continues from), with the same application and recording id; ``python -m lifelong_evo view RUN``
opens all parts, which the viewer merges into one recording. Generations recorded after the last
checkpoint of the interrupted part are recorded again by the resumed part (with equal values: the
checkpoint holds every random state).

Streaming instead of a file: ``LIFELONG_EVO_RERUN=connect`` sends to a running viewer (start one
with ``rerun``) at ``rerun+http://127.0.0.1:9876/proxy`` or at ``LIFELONG_EVO_RERUN_URL``;
``LIFELONG_EVO_RERUN=both`` does both; ``file`` (the default) writes the file only.
"""
from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np

from envs import COLOR_RGB, color_rgb, task_rgb

from ..episodes import Episode
from ..errors import UserError
from ..metrics import GenerationRecord
from ..networks import NetworkView, columns, describe
from ..recording import Recorder
from ..schedule import distinct_tasks

APPLICATION_ID = "lifelong_evo"
ENV_MODE = "LIFELONG_EVO_RERUN"
ENV_URL = "LIFELONG_EVO_RERUN_URL"
MODES = ("file", "connect", "both")
TRAIL = 20
"""Positions in an agent's trail."""
FLUSH_GENERATIONS = 25
FLUSH_SECONDS = 30.0
"""Curve points are sent every this many generations or seconds (and at drifts, task ends, close)."""
AGENT_RADIUS = 0.5
BOX_RADIUS = 0.3
ARENA_RGB = (200, 200, 200)
DROP_ZONE_RGB = (255, 170, 60)
FAILED_RGB = (110, 60, 20)
"""The colour of a failed robot (it carries nothing, so no box colour is lost)."""
FLOOR_RGB = (70, 72, 80)
NODE_RGB = {"input": (150, 150, 150), "hidden": (240, 200, 80), "output": (90, 170, 250)}
"""A NEAT node's colour by role in the network graph."""


def sink_mode() -> str:
    mode = os.environ.get(ENV_MODE, "").strip().lower() or "file"
    if mode not in MODES:
        raise UserError(f"{ENV_MODE}={mode!r} is not one of {', '.join(MODES)}: unset it to write recording.rrd")
    return mode


def episode_path(generation: int, phase_task: str, task: str) -> str:
    return f"episodes/gen{generation:04d}_{phase_task}/on_{task}"


def expected_episode_paths(config) -> list[tuple[str, str]]:
    """(entity path, view name) of the episodes the loop records at task ends, in order."""
    from ..schedule import distinct_tasks

    phases = config.phases()
    tasks = distinct_tasks(phases)
    names = [p.name for p in phases]
    paths, generation = [], -1
    for i, phase in enumerate(phases):
        generation += phase.generations
        for task in tasks:
            if task.name in names[:i + 1]:
                paths.append((episode_path(generation, phase.name, task.name),
                              f"gen {generation} {phase.name} top on {task.name}"))
    return paths


def make_blueprint(episodes: list[tuple[str, str]], curves: bool = True, graph: bool = True):
    """Curves on the left (current performance above, retention/regularised/species and the top
    individual's network in tabs: a ``graph`` for NEAT, else the layers' distances), the arena on
    the right (one tab per episode, cumulative reward below), the text log below."""
    import rerun.blueprint as rrb

    arenas = [rrb.Spatial2DView(origin=path, name=name, background=FLOOR_RGB) for path, name in episodes]
    if not arenas:
        arenas = [rrb.Spatial2DView(origin="episodes", name="arena (no episode yet)", background=FLOOR_RGB)]
    reward = rrb.TimeSeriesView(origin="/", contents=[f"+ /{path}/reward" for path, _ in episodes] or
                                ["+ /episodes/**/reward"], name="cumulative episode reward (step timeline)")
    right = rrb.Vertical(rrb.Tabs(*arenas), reward, row_shares=[3, 1])
    parts = []
    if curves:
        left = rrb.Vertical(
            rrb.TimeSeriesView(origin="curves/current", name="current task: best and mean fitness"),
            rrb.Tabs(rrb.TimeSeriesView(origin="curves/retention_pop", name="retention: population"),
                     rrb.TimeSeriesView(origin="curves/retention_top", name="retention: top individual"),
                     rrb.TimeSeriesView(origin="curves/regularised", name="regularised fitness"),
                     rrb.TimeSeriesView(origin="curves", contents=["+ /curves/species", "+ /curves/centre/**",
                                                                   "+ /curves/extra/**"],
                                        name="species / centre / optimiser"),
                     rrb.GraphView(origin="network/graph", name="network (task ends)") if graph else
                     rrb.BarChartView(origin="network/layer_distance", name="network: layer distances (task ends)"),
                     rrb.TextDocumentView(origin="network/summary", name="network vs reference")),
            row_shares=[1, 1])
        parts = [rrb.Horizontal(left, right, column_shares=[3, 2])]
    else:
        parts = [right]
    layout = rrb.Vertical(*parts, rrb.TextLogView(origin="log", name="log"), row_shares=[5, 1])
    return rrb.Blueprint(layout, rrb.TimePanel(timeline="generation" if curves else "step"),
                         rrb.SelectionPanel(state="collapsed"), rrb.BlueprintPanel(state="collapsed"),
                         auto_views=False)


class RerunRecorder(Recorder):
    """Writes a run (or a replay) to an .rrd file and/or a viewer; the stream opens at the first
    log call, so that the run directory is created (or cleared by --overwrite) before."""

    wants_episodes = True

    def __init__(self, path: Path | None, *, recording_id: str, recording_name: str, arena_size: float,
                 blueprint=None, mode: str = "file"):
        self.path = Path(path) if path is not None else None
        self.recording_id = recording_id
        self.recording_name = recording_name
        self.arena_size = float(arena_size)
        self.blueprint = blueprint
        self.mode = mode
        self._stream = None
        self._styled: set[str] = set()
        self._pending: dict[str, list[tuple[int, float]]] = {}
        self._pending_rows = 0
        self._last_flush = time.monotonic()
        self.episodes_logged: list[str] = []
        self.episode_views: list[tuple[str, str]] | None = None
        """The arena tabs of the blueprint sent at the start (None: no update at close)."""
        self.task_colors: dict[str, tuple[int, int, int]] = {}
        """The display colour of each task of the run, by name (``for_run`` fills it)."""
        self.graph = True
        """The blueprint shows networks as graphs (NEAT), else as layer distances."""

    @classmethod
    def for_run(cls, run_dir, config, resume: bool) -> "RerunRecorder":
        name = run_dir.path.resolve().name
        path = run_dir.recording_path(resume)
        expected = expected_episode_paths(config)
        recorder = cls(path, recording_id=f"{APPLICATION_ID}/{name}", recording_name=name,
                       arena_size=config.env_config().size, mode=sink_mode(),
                       blueprint=make_blueprint(expected, graph=config.algo == "neat"))
        recorder.graph = config.algo == "neat"
        recorder.episode_views = expected
        recorder.task_colors = {task.name: color_rgb(task.target) for task in distinct_tasks(config.phases())}
        return recorder

    def task_rgb(self, task: str) -> tuple[int, int, int]:
        """A task's display colour: its target colour's (``envs.task_rgb`` for a task the run does not name)."""
        return self.task_colors.get(task) or task_rgb(task)

    # -- stream ---------------------------------------------------------------------------------

    @property
    def stream(self):
        if self._stream is None:
            import rerun as rr

            stream = rr.RecordingStream(APPLICATION_ID, recording_id=self.recording_id)
            url = os.environ.get(ENV_URL) or None
            if self.mode == "connect":
                stream.connect_grpc(url, default_blueprint=self.blueprint)
            elif self.mode == "both":
                stream.set_sinks(rr.FileSink(str(self.path)), rr.GrpcSink(url) if url else rr.GrpcSink(),
                                 default_blueprint=self.blueprint)
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                stream.save(self.path, default_blueprint=self.blueprint)
            stream.send_recording_name(self.recording_name)
            self._stream = stream
        return self._stream

    def _style(self, entity: str, color, name: str, width: float = 2.0) -> None:
        if entity in self._styled:
            return
        import rerun as rr

        self.stream.log(entity, rr.SeriesLines(colors=[color], names=[name], widths=[width]), static=True)
        self._styled.add(entity)

    def _scalar(self, generation: int, entity: str, value, color, name: str, width: float = 2.0) -> None:
        """Buffer one curve point; ``flush_curves`` sends the buffer column-wise (a chunk per curve
        and flush instead of one per point keeps a long run's file small)."""
        if value is None or math.isnan(value):  # not measured in this generation
            return
        self._style(entity, color, name, width)
        self._pending.setdefault(entity, []).append((generation, float(value)))

    def flush_curves(self) -> None:
        import rerun as rr

        for entity, points in self._pending.items():
            generations, values = zip(*points)
            self.stream.send_columns(entity, indexes=[rr.TimeColumn("generation", sequence=generations)],
                                     columns=rr.Scalars.columns(scalars=np.array(values, dtype=np.float64)))
        self._pending = {}
        self._pending_rows = 0
        self._last_flush = time.monotonic()

    def text(self, at: int | None, message: str, level: str = "INFO", timeline: str = "generation") -> None:
        """A ``log`` entry at ``at`` on ``timeline``."""
        import rerun as rr

        self.flush_curves()
        if at is not None:
            self.stream.set_time(timeline, sequence=at)
        self.stream.log("log", rr.TextLog(message, level=level))

    # -- Recorder -------------------------------------------------------------------------------

    def log_generation(self, record: GenerationRecord) -> None:
        generation, task = record.generation, record.task
        if generation == 0 and record.generation_in_task == 0:
            self.text(generation, f"run {self.recording_name}: task {task} from generation 0. "
                                  "Episodes play on the 'step' timeline (pick it in the time panel).")
        color = self.task_rgb(task)
        light = tuple(int(c + (255 - c) * 0.45) for c in color)
        for kind, stats, label in (("current", record.fitness, ""), ("regularised", record.regularised, " regularised")):
            self._scalar(generation, f"curves/{kind}/{task}/best", stats.best, color, f"{task}{label} best", 2.0)
            self._scalar(generation, f"curves/{kind}/{task}/mean", stats.mean, light, f"{task}{label} mean", 1.0)
        self._scalar(generation, f"curves/current/{task}/top", record.top, color, f"{task} top individual", 1.5)
        if record.centre is not None:
            self._scalar(generation, f"curves/centre/{task}", record.centre, color, f"{task} centre", 1.5)
        if record.species_sizes is not None:
            self._scalar(generation, "curves/species", len(record.species_sizes), (220, 220, 220), "species", 1.5)
        for other, kept in record.retention.items():
            for level, width in (("pop", 2.0), ("top", 1.5), ("centre", 1.0)):
                self._scalar(generation, f"curves/retention_{level}/{other}", getattr(kept, level), self.task_rgb(other),
                             f"{other} retention ({level})", width)
        for name, value in record.diagnostics.items():
            self._scalar(generation, f"curves/extra/{name}", value, (200, 200, 200), name, 1.0)
        self._pending_rows += 1
        if self._pending_rows >= FLUSH_GENERATIONS or time.monotonic() - self._last_flush > FLUSH_SECONDS \
                or self.mode != "file":
            self.flush_curves()

    def log_drift(self, generation: int, previous: str, task: str) -> None:
        # a NaN breaks the line of each series that pauses here (the previous task's current
        # performance, the new task's retention), so that the viewer does not join its phases
        pausing = [f"curves/{kind}/{previous}/{stat}" for kind in ("current", "regularised")
                   for stat in ("best", "mean")]
        pausing += [f"curves/current/{previous}/top"]
        pausing += [f"curves/centre/{previous}"]
        pausing += [f"curves/retention_{level}/{task}" for level in ("pop", "top", "centre")]
        for entity in pausing:
            if entity in self._styled:
                self._pending.setdefault(entity, []).append((generation, math.nan))
        self.text(generation, f"generation {generation}: drift {previous} -> {task}", level="WARN")

    def log_episode(self, generation: int, phase_index: int, phase_task: str, task, episode: Episode) -> None:
        path = episode_path(generation, phase_task, task.name)
        self.log_episode_at(path, episode, generation=generation)
        self.text(generation, f"generation {generation}: end of phase {phase_index} ({phase_task}); its top "
                              f"individual earns {episode.total_reward:g} on {task.name} ({path})")

    def log_network(self, generation: int, view: NetworkView) -> None:
        import rerun as rr

        self.flush_curves()
        stream = self.stream
        stream.set_time("generation", sequence=generation)
        lines = [f"## {describe(view)}", ""]
        network = view.network
        if view.is_neat:
            column = columns(network)
            rows: dict[int, int] = {}
            positions = []
            for key, _ in network.nodes:  # nodes stacked within their column
                positions.append((150.0 * column[key], 40.0 * rows.get(column[key], 0)))
                rows[column[key]] = rows.get(column[key], 0) + 1
            stream.log("network/graph", rr.GraphNodes(
                [str(key) for key, _ in network.nodes], positions=positions,
                colors=[NODE_RGB[role] for _, role in network.nodes],
                labels=[f"{role} {key}" for key, role in network.nodes]))
            links = network.connections
            stream.log("network/graph", rr.GraphEdges([(str(e.source), str(e.target)) for e in links],
                                                      graph_type="directed"),
                       rr.AnyValues(weight=[e.weight for e in links], new=[e.new for e in links]))
            lines += ["| from | to | weight | new |", "|---|---|---|---|"]
            lines += [f"| {e.source} | {e.target} | {e.weight:.4g} | {'yes' if e.new else ''} |" for e in links]
        else:
            sizes = network.layer_sizes
            if network.layer_distances:
                stream.log("network/layer_distance", rr.BarChart(np.array(network.layer_distances, dtype=np.float64)))
            lines += ["| layer | size | distance |", "|---|---|---|"]
            distances = network.layer_distances or [None] * (len(sizes) - 1)
            lines += [f"| {i + 1} | {a} -> {b} | {'' if d is None else f'{d:.4g}'} |"
                      for i, (a, b, d) in enumerate(zip(sizes, sizes[1:], distances))]
        stream.log("network/summary", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN))

    def log_episode_at(self, path: str, episode: Episode, generation: int | None = None) -> None:
        """One episode under ``path`` on the ``step`` timeline (and at ``generation``, if given)."""
        import rerun as rr

        self.flush_curves()
        stream = self.stream
        self.episodes_logged.append(path)
        size = self.arena_size
        corners = np.array([[0, 0], [size, 0], [size, size], [0, size], [0, 0]], dtype=np.float32)
        stream.log(f"{path}/arena", rr.LineStrips2D([corners], colors=[ARENA_RGB], radii=[0.08]), static=True)
        stream.log(f"{path}/drop_zone", rr.LineStrips2D([drop_zone_outline(episode.drop_zone, size)],
                                                         colors=[DROP_ZONE_RGB], radii=[0.06],
                                                         labels=[f"drop zone ({episode.drop_zone})"]), static=True)
        stream.log(f"{path}/agents", rr.Points2D.from_fields(radii=[AGENT_RADIUS]), static=True)
        stream.log(f"{path}/boxes", rr.Points2D.from_fields(radii=[BOX_RADIUS]), static=True)
        stream.log(f"{path}/trails", rr.LineStrips2D.from_fields(radii=[0.05]), static=True)
        stream.log(f"{path}/reward", rr.SeriesLines(colors=[color_rgb(episode.target)],
                                                    names=[f"{path.split('/', 1)[1]} reward"]), static=True)

        steps, agents = episode.agent_pos.shape[:2]
        screen = episode.agent_pos[..., ::-1].astype(np.float32)  # (x, y) -> screen (y, x)

        def indexes(rows: np.ndarray):
            columns = [rr.TimeColumn("step", sequence=rows)]
            if generation is not None:
                columns.append(rr.TimeColumn("generation", sequence=np.full(len(rows), generation)))
            return columns

        all_steps = np.arange(steps)
        carried = episode.carried_color
        palette = _palette()
        agent_colors = palette[np.clip(carried, 0, len(palette) - 1)]
        agent_colors[:, agents - episode.failed_robots:] = FAILED_RGB
        agent_colors = agent_colors.reshape(-1, 3)
        stream.send_columns(f"{path}/agents", indexes=indexes(all_steps),
                            columns=rr.Points2D.columns(positions=screen.reshape(-1, 2),
                                                        colors=agent_colors).partition([agents] * steps))
        # trails: per step, each agent's last TRAIL positions (fewer at the start)
        lengths = np.minimum(all_steps + 1, TRAIL)
        strips = [screen[t + 1 - lengths[t]:t + 1, a] for t in range(steps) for a in range(agents)]
        stream.send_columns(f"{path}/trails", indexes=indexes(all_steps),
                            columns=rr.LineStrips2D.columns(strips=strips,
                                                            colors=agent_colors).partition([agents] * steps))
        # boxes: only the steps where a box moved, appeared or vanished (the viewer holds the rest)
        box_screen = episode.box_pos[..., ::-1].astype(np.float32)
        present = episode.box_present.astype(bool)
        changed = np.ones(steps, dtype=bool)
        changed[1:] = (present[1:] != present[:-1]).any(axis=1) | \
            ((box_screen[1:] != box_screen[:-1]).any(axis=2) & present[1:]).any(axis=1)
        rows = np.flatnonzero(changed)
        box_colors = palette[np.clip(episode.box_color, 0, len(palette) - 1)]
        counts = present[rows].sum(axis=1)
        positions = np.concatenate([box_screen[t][present[t]] for t in rows]) if counts.sum() else \
            np.zeros((0, 2), np.float32)
        colors = np.concatenate([box_colors[present[t]] for t in rows]) if counts.sum() else \
            np.zeros((0, 3), np.uint8)
        stream.send_columns(f"{path}/boxes", indexes=indexes(rows),
                            columns=rr.Points2D.columns(positions=positions, colors=colors).partition(counts))
        cumulative = np.concatenate([[0.0], np.cumsum(episode.rewards, dtype=np.float64)])[:steps]
        stream.send_columns(f"{path}/reward", indexes=[rr.TimeColumn("step", sequence=all_steps)],
                            columns=rr.Scalars.columns(scalars=cumulative))

    def close(self) -> None:
        if self._pending:
            self.flush_curves()
        if self._stream is not None and self.episode_views is not None:
            known = {path for path, _ in self.episode_views}
            extra = [(path, path.split("/", 1)[1]) for path in self.episodes_logged if path not in known]
            if extra:  # episodes the schedule did not predict (e.g. every few generations): show them too
                views = sorted(self.episode_views + extra)
                self._stream.send_blueprint(make_blueprint(views, graph=self.graph), make_active=False,
                                            make_default=True)
        if self._stream is not None:
            self._stream.flush()
            self._stream.disconnect()
            self._stream = None


def drop_zone_outline(drop_zone: str, size: float) -> np.ndarray:
    """The outline of the nest, 1 unit deep along its edge, in screen coordinates ``(y, x)``."""
    x0, x1, y0, y1 = {"top": (0, 1, 0, size), "bottom": (size - 1, size, 0, size),
                      "left": (0, size, 0, 1), "right": (0, size, size - 1, size)}[drop_zone]
    return np.array([[y0, x0], [y1, x0], [y1, x1], [y0, x1], [y0, x0]], dtype=np.float32)


def _palette() -> np.ndarray:
    """RGB by colour id, from 0 (nothing carried) to one past the highest known id, so that an
    id clipped to the last entry shows as unknown."""
    return np.array([color_rgb(i) for i in range(max(COLOR_RGB) + 2)], dtype=np.uint8)
