"""NEAT state as JSON: neat-python's genomes, genes, species and innovation tracker without pickle.

``dumps(values, types)`` turns a dict of named values into JSON text; ``loads(text, types)``
gives the dict back. ``types`` maps a kind name (``"genome"``, ``"node"``, ...) to the class
that kind is rebuilt as; ``object_types`` makes it from a neat-python configuration. The
classes come from the caller, never from the text, and an object is rebuilt as pickle rebuilds
it, ``cls.__new__(cls)`` and its instance attributes set, without running ``__init__``: loading
runs no code named by the file.

The format: ``{"format": FORMAT, "objects": [[kind, {attribute: value}], ...], "values":
{name: value}}``. Every object of a class in ``types`` (genomes, genes, species...) is stored
once, with all its instance attributes, in ``objects``, and referenced by its index wherever it
occurs, so objects shared between places (a species representative that is also in the
population, the best genome that is also an elite) are one object again after loading. Values
are JSON ``null``, booleans, integers, strings and lists as themselves; finite floats as JSON
numbers (Python writes the shortest text that reads back to the same double, so every bit
round-trips); the rest as objects with a single key: ``{"float": "nan" | "inf" | "-inf"}``,
``{"tuple": [...]}``, ``{"dict": [[key, value], ...]}`` (insertion order kept: neat-python
iterates dicts) and ``{"object": index}``.

Contract for genome, gene and species classes (neat-python's, and subclasses of them): their
whole state is their instance attributes (no ``__slots__``), holding only the values above,
references to other objects of the kinds in ``types``, and containers of those. Anything else
is refused by ``dumps`` with a ``TypeError`` naming where it was, so a subclass that adds state
this format cannot hold fails at its first checkpoint rather than resuming differently.
"""
from __future__ import annotations

import json
import math
from typing import Any, Mapping

import neat.species

FORMAT = "lifelong-evo/neat-state/1"


def object_types(config, species_set, reproduction) -> dict[str, type]:
    """The classes a NEAT run's objects are rebuilt as: genome and gene classes from its
    configuration, the species class its species set uses, its innovation tracker's class."""
    gc = config.genome_config
    some_species = next(iter(species_set.species.values()), None)
    kinds = {"genome": config.genome_type, "node": gc.node_gene_type, "connection": gc.connection_gene_type,
             "species": neat.species.Species if some_species is None else type(some_species)}
    if reproduction.innovation_tracker is not None:
        kinds["innovation_tracker"] = type(reproduction.innovation_tracker)
    return kinds


# Every attribute of neat-python's reproduction, stagnation and species set: the state the
# optimiser stores (counters, ancestors, innovation tracker, species) and the wiring their
# constructors rebuild from the configuration.
_COMPONENT_ATTRIBUTES = {
    "reproduction": {"reproduction_config", "reporters", "stagnation", "genome_indexer", "ancestors",
                     "innovation_tracker"},
    "stagnation": {"stagnation_config", "species_fitness_func", "reporters"},
    "species set": {"species_set_config", "reporters", "indexer", "species", "genome_to_species"},
}


def check_components(reproduction, species_set) -> None:
    """Refuse components with attributes neat-python's own do not have: the optimiser stores
    the state of those (``NeatOptimizer.state_dict``), and more would be lost on resume."""
    for role, component in (("reproduction", reproduction), ("stagnation", reproduction.stagnation),
                            ("species set", species_set)):
        extra = sorted(set(vars(component)) - _COMPONENT_ATTRIBUTES[role])
        if extra:
            raise TypeError(f"the {role} {type(component).__qualname__} has state a NEAT checkpoint does not "
                            f"store: {', '.join(extra)} (see algorithms/neat/state.py)")


def dumps(values: Mapping[str, Any], types: Mapping[str, type]) -> str:
    kind_of = {cls: kind for kind, cls in types.items()}
    if len(kind_of) != len(types):
        raise ValueError(f"two kinds share a class: {dict(types)}")
    objects: list = []
    index_of: dict[int, int] = {}

    def encode(value, where: str):
        kind = type(value)
        if value is None or kind in (bool, int, str):
            return value
        if kind is float:
            return value if math.isfinite(value) else {"float": repr(value)}
        if kind is list:
            return [encode(v, where) for v in value]
        if kind is tuple:
            return {"tuple": [encode(v, where) for v in value]}
        if kind is dict:
            return {"dict": [[encode(k, where), encode(v, where)] for k, v in value.items()]}
        if kind in kind_of:
            index = index_of.get(id(value))
            if index is None:
                index = index_of[id(value)] = len(objects)
                entry = [kind_of[kind], None]
                objects.append(entry)
                entry[1] = {name: encode(v, f"{kind_of[kind]}.{name}") for name, v in vars(value).items()}
            return {"object": index}
        raise TypeError(f"cannot store a {kind.__module__}.{kind.__qualname__} (in {where}) in a NEAT checkpoint")

    encoded = {name: encode(value, name) for name, value in values.items()}
    return json.dumps({"format": FORMAT, "objects": objects, "values": encoded},
                      allow_nan=False, separators=(",", ":"))


def loads(text: str, types: Mapping[str, type]) -> dict[str, Any]:
    document = json.loads(text)
    if document.get("format") != FORMAT:
        raise ValueError(f"not a NEAT state (format {document.get('format')!r}, expected {FORMAT!r})")
    entries = document["objects"]
    unknown = sorted({kind for kind, _ in entries} - set(types))
    if unknown:
        raise ValueError(f"NEAT state has objects of unknown kinds {unknown}")
    # every object exists before any attribute is decoded, so references may point forward
    objects = [types[kind].__new__(types[kind]) for kind, _ in entries]

    def decode(value):
        if isinstance(value, list):
            return [decode(v) for v in value]
        if not isinstance(value, dict):
            return value
        (tag, inner), = value.items()
        if tag == "float":
            return float(inner)
        if tag == "tuple":
            return tuple(decode(v) for v in inner)
        if tag == "dict":
            return {decode(k): decode(v) for k, v in inner}
        if tag == "object":
            return objects[inner]
        raise ValueError(f"NEAT state has an unknown tag {tag!r}")

    for obj, (_, attributes) in zip(objects, entries):
        obj.__dict__.update({name: decode(v) for name, v in attributes.items()})
    return {name: decode(value) for name, value in document["values"].items()}
