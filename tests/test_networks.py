"""What a regulariser keeps (``lifelong_evo.networks``, drawn by ``algorithms.network_from_export``):
each task end's top controller against the reference its generation was regularised against,
written beside it (``task<i>-<task>-reference.json``), in the recording and as ``plot``'s PNGs,
from the same controllers."""
from __future__ import annotations

import json
import math
import shutil
from collections import defaultdict
from pathlib import Path

import pytest
import torch

from algorithms import ESOptimizer, NeatOptimizer, make_optimizer, network_from_export
from algorithms.mlp import n_parameters, unflatten
from algorithms.neat.genetics import GENETICS
from algorithms.neat.optimizer import weight_protection
from lifelong_evo.analysis import figures as plots
from lifelong_evo.commands.cli import main
from lifelong_evo.networks import describe, task_end_view, task_end_views

rerun_chunk = pytest.importorskip("rerun.chunk")
PNG = b"\x89PNG\r\n\x1a\n"
PHASES = ["red", "green", "red"]
ENDS = ("task0-red", "task1-green", "task2-red")
END_GENERATIONS = (1, 3, 5)
"""The task ends of ``red:2,green:2,red:2``."""


# ------------------------------------------------------------------ the algorithms' drawings


@pytest.mark.parametrize("genetics", GENETICS)
def test_neat_distance_is_the_regularisers(genetics):
    """The genetic distance drawn is the one the regulariser penalises: the reference it took at
    the task end (an elite, so in the next population) against every genome (under 2.0 the genomes
    rebuilt from their exports have the time constant the distance reads)."""
    optimizer = make_optimizer("neat", obs_dim=31, population_size=20, seed=3, reg=1.0, genetics=genetics)
    optimizer.ask()
    fitness = torch.rand(optimizer.population_size, generator=torch.Generator().manual_seed(0))
    optimizer.tell(fitness, fitness)
    optimizer.end_task()
    genomes = optimizer.ask() and optimizer.asked_genomes
    anchor = optimizer.reference_export()
    expected = optimizer.distances_to_references().tolist()
    measured = [network_from_export(optimizer.export(i), anchor, "gd").measures for i in range(len(genomes))]
    assert [dict(m)["genetic distance"] for m in measured] == pytest.approx(expected, rel=1e-12)
    assert min(expected) == 0.0 and max(expected) > 0


def test_a_neat_reference_is_exported_without_a_generation():
    """README: a task end's reference file is the export format without ``generation``. NEAT's wrote
    the generation the optimiser was at (not the reference's) into ``network.metadata``, so the same
    reference exported differently every generation; a top controller's export keeps its own."""
    optimizer = make_optimizer("neat", obs_dim=31, population_size=20, seed=3, reg=1.0)
    exports = []
    for generation in range(3):
        optimizer.ask()
        fitness = torch.rand(optimizer.population_size, generator=torch.Generator().manual_seed(generation))
        optimizer.tell(fitness, fitness)
        if generation == 0:
            optimizer.end_task()
        exports.append(optimizer.reference_export())
    assert exports[1] == exports[2] and "generation" not in exports[2]["network"]["metadata"]
    optimizer.ask()
    assert optimizer.export(0)["network"]["metadata"]["generation"] == 3


def test_under_weight_protection_neat_measures_its_two_sums():
    """``wp`` penalises lambda_1 times the squared changes of the weights the reference has plus
    lambda_2 times the squared weights it lacks: the drawing gives those two sums, not the
    genetic distance, which ``wp`` does not measure."""
    optimizer = make_optimizer("neat", obs_dim=31, population_size=20, seed=4, reg=0.4, penalty="wp")
    optimizer.ask()
    exported, other = optimizer.export(0), optimizer.export(1)
    shared, new = weight_protection(*(optimizer.asked_genomes[i] for i in (0, 1)))
    measures = network_from_export(exported, other, "wp").measures  # summed in the export's order
    assert [what for what, _ in measures] == ["sum of squared weight changes", "sum of squared new weights"]
    assert [value for _, value in measures] == pytest.approx([shared, new], rel=1e-12)
    assert shared > 0 and new > 0
    assert [what for what, _ in network_from_export(exported, other, "functional").measures] == ["genetic distance"]


def test_neat_drawing_shows_enabled_connections_and_marks_the_new_ones():
    optimizer = make_optimizer("neat", obs_dim=31, population_size=20, seed=4)
    optimizer.ask()
    exported, other = optimizer.export(0), optimizer.export(1)
    network = network_from_export(exported, other, "gd")
    enabled = [c for c in exported["genome"]["connections"] if c["enabled"]]
    links = network.connections
    assert [(e.source, e.target, e.weight) for e in links] == [(c["in"], c["out"], c["weight"]) for c in enabled]
    theirs = {(c["in"], c["out"]) for c in other["genome"]["connections"] if c["enabled"]}
    assert [e.new for e in links] == [(c["in"], c["out"]) not in theirs for c in enabled]
    assert any(e.new for e in links) and not all(e.new for e in links)
    assert {key for key, role in network.nodes if role == "input"} == {c["in"] for c in enabled if c["in"] < 0}
    assert [key for key, role in network.nodes if role == "output"] == [0, 1, 2]
    alone = network_from_export(exported)
    assert alone.measures == () and not any(e.new for e in alone.connections)


def test_mlp_drawing_measures_each_layer():
    sizes = [5, 4, 3]
    reference = {"layer_sizes": sizes, "parameters": [0.0] * n_parameters(sizes)}
    moved = {"layer_sizes": sizes, "parameters": [1.0] * (5 * 4 + 4) + [0.0] * (4 * 3 + 3)}
    network = network_from_export(moved, reference, "ewc")
    assert network.layer_sizes == (5, 4, 3) and network.layer_distances == pytest.approx([24 ** 0.5, 0.0])
    assert network.measures == (("Euclidean distance", pytest.approx(24 ** 0.5)),)


def test_the_line_names_what_was_measured_against_which_file_under_which_regulariser():
    sizes = [5, 4, 3]
    top = {"layer_sizes": sizes, "parameters": [1.0] * n_parameters(sizes)}
    reference = {"layer_sizes": sizes, "parameters": [0.0] * n_parameters(sizes)}
    controllers = {"task1-green-top": top, "task1-green-reference": reference}
    es = {"algo": "sep-cmaes", "reg": 2.0, "regulariser": "ewc"}
    line = describe(task_end_view(es, ["red", "green"], 1, controllers))
    assert line == (f"task1-green-top: layers 5 -> 4 -> 3; Euclidean distance {math.sqrt(39):.3g} to "
                    "task1-green-reference; regulariser ewc, lambda 2")
    assert describe(task_end_view({**es, "reg": 0}, ["red", "green"], 1, controllers)).endswith(
        "; regulariser ewc off (lambda 0)")
    assert "reference unknown (no task1-green-reference:" in describe(
        task_end_view(es, ["red", "green"], 1, {"task1-green-top": top}))


def test_a_neat_line_counts_the_connections_its_reference_lacks():
    optimizer = make_optimizer("neat", obs_dim=31, population_size=20, seed=4)
    optimizer.ask()
    top, other = optimizer.export(0), optimizer.export(1)
    neat = {"algo": "neat", "reg": 11.0, "regulariser": "gd"}
    theirs = {(c["in"], c["out"]) for c in other["genome"]["connections"] if c["enabled"]}
    lacked = sum((c["in"], c["out"]) not in theirs for c in top["genome"]["connections"] if c["enabled"])
    line = describe(task_end_view(neat, ["red"], 0, {"task0-red-top": top, "task0-red-reference": other}))
    assert lacked > 0 and f"to task0-red-reference, which lacks {lacked} of them; regulariser gd" in line, line
    line = describe(task_end_view(neat, ["red"], 0, {"task0-red-top": top, "task0-red-reference": top}))
    assert "genetic distance 0 to task0-red-reference, which has all of them;" in line, line


# ------------------------------------------------------------------ runs: the loop, the recording and plot


def _network_rows(path: Path) -> dict[str, list[dict]]:
    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in rerun_chunk.RrdReader(path).stream().to_chunks():
        if not chunk.is_static and chunk.entity_path.lstrip("/").startswith("network/"):
            rows[chunk.entity_path.lstrip("/")].extend(chunk.to_record_batch().to_pylist())
    return rows


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two recorded runs of ``red:2,green:2,red:2``, and what their optimisers held:

    - ``neat``, taking its reference every 3 generations (at generations 2 and 5), so that each
      task end's reference is the best genome of generations the loop exports nothing of, not the
      previous task end's top one (at seed 2: at others, an elite that the task ends export as
      their top too); ``penalties``: per generation, the distance to the reference
      that the regulariser subtracted from each genome's fitness, and the selection fitness;
    - ``sep-cmaes``, taking it at task ends; ``centres``: the centre each ``end_task`` took (after
      the task's last update, one update past the task end's exported centre)."""
    out = tmp_path_factory.mktemp("networks")
    penalties, centres = [], []
    regularise, end_task = NeatOptimizer.regularise, ESOptimizer.end_task

    def kept_penalty(self, fitness):
        selection = regularise(self, fitness)
        distances = self.distances_to_references()
        penalties.append((None if distances is None else distances.clone(), selection.clone()))
        return selection

    def kept_centre(self):
        centres.append(self.centre.detach().clone())
        end_task(self)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(NeatOptimizer, "regularise", kept_penalty)
        patch.setattr(ESOptimizer, "end_task", kept_centre)
        for algo, flags in (("neat", ["--reference-every", "3", "--seed", "2"]), ("sep-cmaes", [])):
            assert main(["--algo", algo, "--reg", "1", "--preset", "smoke", "--schedule", "red:2,green:2,red:2",
                         "--env", "duration=60", *flags, "--out", str(out), "--name", algo, "--quiet"]) == 0
    return out, penalties, centres


def _controllers(run: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in (run / "controllers").glob("*.json")}


def _views(run: Path):
    """What ``plot`` draws of ``run``: every task end's view, from its files."""
    return dict(task_end_views(json.loads((run / "config.json").read_text()), PHASES, _controllers(run),
                               run / "controllers"))


def test_neat_is_drawn_against_the_reference_it_was_regularised_against(runs):
    """The genetic distance drawn at a task end is the one the regulariser subtracted from the top
    genome's fitness in that generation, to a genome of a generation the loop exported nothing
    of: neither the previous task end's top genome nor one of this task's."""
    out, penalties, _ = runs
    controllers, views = _controllers(out / "neat"), _views(out / "neat")
    assert "task0-red-reference" not in controllers  # no reference before generation 2
    assert not views[0].found
    tops = [controllers[f"{end}-top"]["genome"] for end in ENDS]
    for i in (1, 2):
        assert controllers[f"{ENDS[i]}-reference"]["genome"] not in tops  # the test bites on the old rule
        distances, selection = penalties[END_GENERATIONS[i]]
        top = int(selection.argmax())
        assert views[i].found and dict(views[i].network.measures)["genetic distance"] == pytest.approx(
            distances[top].item(), rel=1e-12)
    # one reference (taken at generation 2) for both task ends: the distances differ only by the top genome
    assert controllers["task1-green-reference"]["genome"] == controllers["task2-red-reference"]["genome"]


def test_an_es_is_drawn_against_the_centre_after_its_last_update(runs):
    """The reference an ES takes at a task end is its centre after the task's last update, one
    update past the centre exported at that task end (before that update)."""
    out, _, centres = runs
    controllers, views = _controllers(out / "sep-cmaes"), _views(out / "sep-cmaes")
    assert "task0-red-reference" not in controllers
    for i in (1, 2):
        reference = torch.tensor(controllers[f"{ENDS[i]}-reference"]["parameters"])
        assert torch.equal(reference, centres[i - 1])
        exported_centre = torch.tensor(controllers[f"{ENDS[i - 1]}-centre"]["parameters"])
        assert not torch.equal(reference, exported_centre)  # the test bites on the exported centre
        sizes = controllers[f"{ENDS[i]}-top"]["layer_sizes"]
        top = torch.tensor(controllers[f"{ENDS[i]}-top"]["parameters"], dtype=torch.float64)
        layers = zip(unflatten(top, sizes), unflatten(centres[i - 1].double(), sizes))
        expected = [math.sqrt(((w - v) ** 2).sum() + ((b - c) ** 2).sum()) for (w, b), (v, c) in layers]
        assert views[i].network.layer_distances == pytest.approx(expected, rel=1e-12)


def test_the_recording_draws_what_plot_draws(runs):
    """At each task end (generations 1, 3, 5) the recording holds the top controller's graph (NEAT:
    its enabled connections with their weights, the new ones against the reference) or its layer
    distances (ES), and the line describing it, as ``plot`` computes them from the files."""
    out = runs[0]
    neat = _network_rows(out / "neat/recording.rrd")
    graphs = {row["generation"]: row for row in neat["network/graph"] if row.get("GraphEdges:edges")}
    nodes = {row["generation"]: row for row in neat["network/graph"] if row.get("GraphNodes:node_ids")}
    summaries = {row["generation"]: row["TextDocument:text"][0] for row in neat["network/summary"]}
    views = _views(out / "neat")
    assert sorted(graphs) == sorted(nodes) == sorted(summaries) == list(END_GENERATIONS)
    for i, generation in enumerate(END_GENERATIONS):
        links = views[i].network.connections
        assert graphs[generation]["GraphEdges:edges"] == [{"first": str(e.source), "second": str(e.target)}
                                                         for e in links]
        assert graphs[generation]["weight"] == [e.weight for e in links]
        assert graphs[generation]["new"] == [e.new for e in links]
        assert nodes[generation]["GraphNodes:node_ids"] == [str(key) for key, _ in views[i].network.nodes]
        assert summaries[generation].startswith(f"## {describe(views[i])}\n")
    assert "genetic distance" in summaries[3] and "regulariser gd, lambda 1" in summaries[3]

    es = _network_rows(out / "sep-cmaes/recording.rrd")
    bars = {row["generation"]: row["BarChart:values"][0]["buffer"] for row in es["network/layer_distance"]}
    views = _views(out / "sep-cmaes")
    assert sorted(bars) == [3, 5]  # the first task end has no reference
    assert bars[3] == pytest.approx(views[1].network.layer_distances, rel=1e-12)
    assert bars[5] == pytest.approx(views[2].network.layer_distances, rel=1e-12)
    summaries = {row["generation"]: row["TextDocument:text"][0] for row in es["network/summary"]}
    assert all(summaries[g].startswith(f"## {describe(views[i])}\n") for i, g in enumerate(END_GENERATIONS))


def _titles(monkeypatch) -> dict[str, tuple[str, list[int], list[int], bool]]:
    """Each figure plot saves, by file name: its title, per axes its lines and patches, and whether
    the title lies within the figure's width as drawn."""
    drawn = {}
    save = plots.save

    def keep(fig, path):
        axes = fig.axes
        fig.canvas.draw()
        box = axes[0].title.get_window_extent()
        drawn[path.name] = (axes[0].get_title(), [len(ax.lines) for ax in axes], [len(ax.patches) for ax in axes],
                            box.x0 >= 0 and box.x1 <= fig.bbox.width)
        return save(fig, path)

    monkeypatch.setattr(plots, "save", keep)
    return drawn


def test_plot_draws_a_png_per_task_end(runs, tmp_path, monkeypatch):
    drawn = _titles(monkeypatch)
    for algo in ("neat", "sep-cmaes"):
        assert main(["plot", str(runs[0] / algo), "--out", str(tmp_path)]) == 0
        for i, end in enumerate(ENDS):
            name = f"{algo}-red-2-green-2-red-2-reg1-network-{end}.png"
            view = _views(runs[0] / algo)[i]
            assert (tmp_path / name).read_bytes().startswith(PNG)
            title, lines, bars, fits = drawn[name]
            assert title.split("\n", 1)[1].replace("\n", " ") == describe(view)
            assert fits, title  # the ES's narrower figure cut its line off at both sides
            if algo == "neat":
                assert lines == [len(view.network.connections)]  # one line per enabled connection
            else:
                assert bars == [2]  # one bar per layer


def test_plot_of_a_run_without_reference_files_says_the_reference_is_unknown(runs, tmp_path, monkeypatch):
    """A run written before task ends kept their reference is drawn all the same, without a distance."""
    old = tmp_path / "old"
    shutil.copytree(runs[0] / "sep-cmaes", old)
    for path in old.glob("controllers/*-reference.json"):
        path.unlink()
    drawn = _titles(monkeypatch)
    assert main(["plot", str(old), "--out", str(tmp_path / "figures")]) == 0
    title, _, _, _ = drawn["sep-cmaes-red-2-green-2-red-2-reg1-network-task1-green.png"]
    assert "reference unknown (no task1-green-reference" in title and "distance" not in title
