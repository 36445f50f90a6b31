"""The paper's NEAT configuration (``config.ini``, its NEAT table) as a ``neat.Config``.

``build_neat_config`` reads ``config.ini``, sets the run's number of inputs and population size,
takes the genome, reproduction, species-set and stagnation classes of the run's genetics
(``genetics.genetics_version``), and registers the paper's activation ``neat_sigmoid``. Every
option is in the file, so neither neat-python version's defaults matter.
"""
from __future__ import annotations

import configparser
import os
import tempfile
from importlib import resources
from typing import Mapping

import neat

from .genetics import DEFAULT_GENETICS, genetics_version
from .network import neat_sigmoid

CONFIG_FILE = "algorithms/neat/config.ini"
"""Where the configuration lives in the source tree, for messages that point the user to it."""

_SECTIONS = ("DefaultGenome", "DefaultReproduction", "DefaultSpeciesSet", "DefaultStagnation")
"""The sections of ``config.ini`` for the genetics' classes, in ``neat.Config``'s order."""


def neat_config_path() -> str:
    """Path of the packaged ``config.ini`` (the paper's table)."""
    return str(resources.files(__package__).joinpath("config.ini"))


def _read_config() -> configparser.ConfigParser:
    parser = configparser.ConfigParser()
    with open(neat_config_path()) as f:
        parser.read_file(f)
    return parser


def minimum_population(genetics: str = DEFAULT_GENETICS) -> tuple[int, str]:
    """The smallest population NEAT evolves at the size asked with the paper's configuration,
    and why, in words (``GeneticsVersion.minimum_population`` on ``config.ini``'s ``elitism``
    and ``min_species_size``)."""
    parser = _read_config()
    return genetics_version(genetics).minimum_population(
        parser.getint("DefaultReproduction", "elitism"), parser.getint("DefaultReproduction", "min_species_size"))


def build_neat_config(num_inputs: int, pop_size: int = 300,
                      overrides: Mapping[str, Mapping[str, object]] | None = None,
                      genetics: str = DEFAULT_GENETICS) -> neat.Config:
    """A fresh ``neat.Config`` with the paper's values, ``num_inputs`` inputs and ``pop_size``,
    and the classes of ``genetics`` (``genetics.genetics_version``).

    ``overrides`` maps section name (as in ``config.ini``) to ``{option: value}`` and
    replaces further values (tests use it for high mutation rates). Build one per optimiser: the
    config carries mutable counters (the node indexer, and the innovation tracker once
    reproduction sets it).
    """
    if int(num_inputs) < 1:
        raise ValueError(f"num_inputs must be >= 1, got {num_inputs}")
    if int(pop_size) < 2:
        raise ValueError(f"pop_size must be >= 2, got {pop_size}")
    parser = _read_config()
    parser["NEAT"]["pop_size"] = str(int(pop_size))
    parser["DefaultGenome"]["num_inputs"] = str(int(num_inputs))
    for section, values in (overrides or {}).items():
        for key, value in values.items():
            if not parser.has_option(section, key):
                raise KeyError(f"unknown NEAT option [{section}] {key}")
            parser[section][key] = str(value)
    components = genetics_version(genetics).components
    # neat-python reads each component's options from the section named after its class
    for section, component in zip(_SECTIONS, components):
        if section != component.__name__:
            parser[component.__name__] = dict(parser[section])
            parser.remove_section(section)
    fd, path = tempfile.mkstemp(prefix="neat-config-", suffix=".ini")
    try:
        with os.fdopen(fd, "w") as f:
            parser.write(f)
        config = neat.Config(*components, path)
    finally:
        os.unlink(path)
    config.genome_config.add_activation("neat_sigmoid", neat_sigmoid)
    return config


__all__ = ["CONFIG_FILE", "build_neat_config", "minimum_population", "neat_config_path"]
