"""What a regulariser keeps (``lifelong_evo.networks``): each task end's top controller as a
network against its reference, in the recording and as ``plot``'s PNGs, from the same files."""
from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import pytest
import torch

from algorithms import make_optimizer
from algorithms.mlp import n_parameters
from algorithms.neat.genetics import GENETICS
from lifelong_evo.analysis import figures as plots
from lifelong_evo.commands.cli import main
from lifelong_evo.networks import network_view, reference_name, task_end_views

rerun_chunk = pytest.importorskip("rerun.chunk")
PNG = b"\x89PNG\r\n\x1a\n"
ENDS = ("task0-red", "task1-green", "task2-red")


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
    anchor = optimizer.export(genomes.index(optimizer.reference_genomes[-1]))
    expected = optimizer.distances_to_references().tolist()
    views = [network_view(f"g{i}", optimizer.export(i), "anchor", anchor) for i in range(len(genomes))]
    assert [view.distance for view in views] == pytest.approx(expected, rel=1e-12)
    assert min(view.distance for view in views) == 0.0 and max(expected) > 0


def test_neat_view_draws_enabled_connections_and_marks_the_new_ones():
    optimizer = make_optimizer("neat", obs_dim=31, population_size=20, seed=4)
    optimizer.ask()
    exported, other = optimizer.export(0), optimizer.export(1)
    view = network_view("mine", exported, "other", other)
    enabled = [c for c in exported["genome"]["connections"] if c["enabled"]]
    assert [(e.source, e.target, e.weight) for e in view.edges] == [(c["in"], c["out"], c["weight"]) for c in enabled]
    theirs = {(c["in"], c["out"]) for c in other["genome"]["connections"] if c["enabled"]}
    assert [e.new for e in view.edges] == [(c["in"], c["out"]) not in theirs for c in enabled]
    assert any(e.new for e in view.edges) and not all(e.new for e in view.edges)
    assert {n.key for n in view.nodes if n.role == "input"} == {c["in"] for c in enabled if c["in"] < 0}
    assert [n.key for n in view.nodes if n.role == "output"] == [0, 1, 2]
    assert all(n.depth == 0 for n in view.nodes if n.role == "input")
    assert network_view("mine", exported).distance is None and not any(e.new for e in network_view("m", exported).edges)


def test_mlp_view_measures_each_layer():
    sizes = [5, 4, 3]
    reference = {"layer_sizes": sizes, "parameters": [0.0] * n_parameters(sizes)}
    moved = {"layer_sizes": sizes, "parameters": [1.0] * (5 * 4 + 4) + [0.0] * (4 * 3 + 3)}
    view = network_view("moved", moved, "reference", reference)
    assert view.layer_sizes == (5, 4, 3) and view.layer_distances == pytest.approx([24 ** 0.5, 0.0])
    assert view.distance == pytest.approx(24 ** 0.5)


def test_the_reference_is_the_previous_task_ends_of_the_regularisers_kind():
    names = ["red", "green", "red"]
    assert reference_name({"algo": "neat"}, names, 0) is None
    assert reference_name({"algo": "neat"}, names, 2) == "task1-green-top"
    assert reference_name({"algo": "sep-cmaes", "algo_options_resolved": {"reference": "centre"}}, names, 1) == \
        "task0-red-centre"
    assert reference_name({"algo": "openai-es", "algo_options": {"reference": "best"}}, names, 1) == "task0-red-top"


def _network_rows(path: Path) -> dict[str, list[dict]]:
    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in rerun_chunk.RrdReader(path).stream().to_chunks():
        if not chunk.is_static and chunk.entity_path.lstrip("/").startswith("network/"):
            rows[chunk.entity_path.lstrip("/")].extend(chunk.to_record_batch().to_pylist())
    return rows


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("networks")
    for algo in ("neat", "sep-cmaes"):
        assert main(["--algo", algo, "--reg", "1", "--preset", "smoke", "--schedule", "red:2,green:2,red:2",
                     "--env", "duration=60", "--out", str(out), "--name", algo, "--quiet"]) == 0
    return out


def _views(run: Path):
    controllers = {p.stem: json.loads(p.read_text()) for p in (run / "controllers").glob("*.json")}
    return task_end_views(json.loads((run / "config.json").read_text()), ["red", "green", "red"], controllers)


def test_the_recording_shows_each_task_ends_network(runs):
    """At each task end (generations 1, 3, 5) the recording holds the top controller's graph (NEAT:
    its enabled connections with their weights, the new ones against the previous task end's top
    genome) or its layer distances (ES), as computed from the stored controllers."""
    neat = _network_rows(runs / "neat/recording.rrd")
    graphs = {row["generation"]: row for row in neat["network/graph"] if row.get("GraphEdges:edges")}
    nodes = {row["generation"]: row for row in neat["network/graph"] if row.get("GraphNodes:node_ids")}
    views = dict(_views(runs / "neat"))
    assert sorted(graphs) == sorted(nodes) == [1, 3, 5]
    for i, generation in enumerate((1, 3, 5)):
        view = views[i]
        assert graphs[generation]["GraphEdges:edges"] == [{"first": str(e.source), "second": str(e.target)}
                                                         for e in view.edges]
        assert graphs[generation]["weight"] == [e.weight for e in view.edges]
        assert graphs[generation]["new"] == [e.new for e in view.edges]
        assert nodes[generation]["GraphNodes:node_ids"] == [str(n.key) for n in view.nodes]
    assert views[0].reference is None and views[2].reference == "task1-green-top" and views[2].distance > 0
    summaries = {row["generation"]: row["TextDocument:text"][0] for row in neat["network/summary"]}
    assert f"genetic distance {views[1].distance:.3g} to task0-red-top" in summaries[3]

    es = _network_rows(runs / "sep-cmaes/recording.rrd")
    bars = {row["generation"]: row["BarChart:values"][0]["buffer"] for row in es["network/layer_distance"]}
    views = dict(_views(runs / "sep-cmaes"))
    assert sorted(bars) == [3, 5]  # the first task end has no reference
    assert bars[3] == pytest.approx(views[1].layer_distances) and bars[5] == pytest.approx(views[2].layer_distances)
    assert views[2].reference == "task1-green-centre" and len(views[2].layer_distances) == 2


def test_plot_draws_a_png_per_task_end(runs, tmp_path, monkeypatch):
    drawn = {}
    save = plots.save

    def keep(fig, path):
        drawn[path.name] = [len(ax.lines) for ax in fig.axes], [len(ax.patches) for ax in fig.axes]
        return save(fig, path)

    monkeypatch.setattr(plots, "save", keep)
    for algo in ("neat", "sep-cmaes"):
        assert main(["plot", str(runs / algo), "--out", str(tmp_path)]) == 0
    for algo, views in (("neat", _views(runs / "neat")), ("sep-cmaes", _views(runs / "sep-cmaes"))):
        for (i, view), end in zip(views, ENDS):
            name = f"{algo}-red-2-green-2-red-2-reg1-network-{end}.png"
            assert (tmp_path / name).read_bytes().startswith(PNG)
            lines, bars = drawn[name]
            if algo == "neat":
                assert lines == [len(view.edges)]  # one line per enabled connection
            else:
                assert bars == [2]  # one bar per layer
