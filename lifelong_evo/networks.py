"""What a regulariser keeps: a task end's top controller as a network, set against the reference
the regulariser pulled it towards.

At every task end the loop writes, beside the top controller ``task<i>-<task>-top``, the reference
that the task's last generation was regularised against, ``task<i>-<task>-reference``
(``metrics.REFERENCE``): ``Optimizer.reference_export()`` before ``end_task`` takes the next one,
so whatever rule the run's optimiser and settings take it by (NEAT's best genome of the task by
selection fitness, an ES's centre after its last update or best sample, ``--reference-every``).
A task end without a reference writes none: the first under the default rule, one after
``--from-scratch`` started the optimiser afresh, any of an optimiser without ``reference_export``.
The recording (``Recorder.log_network``, from the controllers the loop writes) and ``plot`` (from
the files) both draw the top controller against that reference (``task_end_view``), so they show
the same numbers; a run written before these files has none, and its drawings say the reference
is unknown.

What a controller is made of and how far it lies from the reference is the algorithm's
(``algorithms.network_from_export``): NEAT's nodes and enabled connections (``new`` where the
reference lacks them) and the genetic distance, or weight protection's two sums under ``wp``; an
MLP's layer sizes and Euclidean distance per layer. This module only lays a network out
(``columns``) and says in one line what was measured against which file under which regulariser
and lambda (``describe``). A measure is named as what it is, not as the penalty: where the
regulariser penalises what the files cannot show (``functional``: outputs; ``ewc``: weighted
parameters; NEAT's ``references`` > 1: the mean over several references, of which the file is the
latest) the line names the regulariser beside the measure.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from algorithms import ControllerNetwork, ExportError, network_from_export

from .config import DEFAULT_REGULARISER, RunConfig
from .errors import RunDirError
from .metrics import REFERENCE, controller_key


@dataclass(frozen=True)
class NetworkView:
    """A task end's top controller as a network, against its reference."""

    controller: str
    """Its name in controllers/ (``task1-green-top``)."""
    reference: str
    """The name its reference has in controllers/ (``task1-green-reference``), whether or not there is one."""
    found: bool
    """Whether there is that reference: ``network`` measures nothing against it otherwise."""
    regulariser: str
    """The run's regulariser and lambda, in words (``regulariser gd, lambda 11``)."""
    network: ControllerNetwork
    """What the algorithm draws of the controller against the reference (``algorithms.network_from_export``)."""

    @property
    def is_neat(self) -> bool:
        return bool(self.network.nodes)


def regulariser_label(config: dict[str, Any]) -> str:
    """The regulariser of a run (config.json's values) and its lambda, in words."""
    name = RunConfig.regulariser_of(config)
    regulariser = "the optimiser's own regulariser" if name == DEFAULT_REGULARISER else f"regulariser {name}"
    reg = float(config.get("reg") or 0)
    return f"{regulariser}, lambda {reg:g}" if reg else f"{regulariser} off (lambda 0)"


def task_end_view(config: dict[str, Any], phase_names: list[str], index: int,
                  controllers: dict[str, dict[str, Any]]) -> NetworkView:
    """Phase ``index``'s top controller against its reference, both taken from ``controllers`` (by
    name, as controllers/ holds them; the top one must be there)."""
    top = controller_key(index, phase_names[index], "top")
    name = controller_key(index, phase_names[index], REFERENCE)
    reference = controllers.get(name)
    regulariser = RunConfig.regulariser_of(config)
    return NetworkView(top, name, reference is not None, regulariser_label(config),
                       network_from_export(controllers[top], reference, regulariser))


def task_end_views(config: dict[str, Any], phase_names: list[str], controllers: dict[str, dict[str, Any]],
                   folder: Path) -> list[tuple[int, NetworkView]]:
    """``(phase index, view)`` of every task end whose top controller ``controllers`` (read from
    the controllers/ ``folder``) has; RunDirError where a reference is not of its top controller's
    family and size (a damaged file)."""
    views = []
    for i, name in enumerate(phase_names):
        if controller_key(i, name, "top") in controllers:
            try:
                views.append((i, task_end_view(config, phase_names, i, controllers)))
            except ExportError as error:
                reference = folder / f"{controller_key(i, name, REFERENCE)}.json"
                raise RunDirError(f"{reference} is not the reference of {controller_key(i, name, 'top')}.json: "
                                  f"{error}: restore it from a copy of the run, or delete it") from None
    return views


def columns(network: ControllerNetwork) -> dict[int, int]:
    """Each NEAT node's column in a drawing, by key: 0 for the inputs, else one more than the
    deepest node feeding it (1 for a node nothing feeds)."""
    depth = {key: 0 if role == "input" else 1 for key, role in network.nodes}
    for _ in network.nodes:  # the longest path from the inputs (the network is feed-forward)
        for link in network.connections:
            depth[link.target] = max(depth[link.target], depth[link.source] + 1)
    return depth


def describe(view: NetworkView) -> str:
    """One line: what the network is, what was measured against which reference, and the regulariser."""
    network = view.network
    if view.is_neat:
        hidden = sum(role == "hidden" for _, role in network.nodes)
        shape = f"{hidden} hidden nodes, {len(network.connections)} enabled connections"
    else:
        shape = "layers " + " -> ".join(map(str, network.layer_sizes))
    if view.found:
        measured = ", ".join(f"{what} {value:.3g}" for what, value in network.measures)
        new = sum(link.new for link in network.connections)
        lacks = (f", which lacks {new} of them" if new else ", which has all of them") if view.is_neat else ""
        against = f"{measured} to {view.reference}{lacks}"
    else:
        against = (f"reference unknown (no {view.reference}: the regulariser had none at this task end, "
                   "or the run was written before runs kept it)")
    return f"{view.controller}: {shape}; {against}; {view.regulariser}"
