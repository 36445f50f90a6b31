"""neat-python 0.92 itself, for the parity test in ``test_neat_genetics.py``.

Run as a script, with NEAT092_DIR a directory holding neat-python 0.92 (never the project's
environment), which it puts first on ``sys.path``::

    python -I neat092_reference.py NEAT092_DIR CONFIG SEED GENERATIONS OUT.json

it seeds ``random``, runs 0.92's own ``Population.run`` with ``fitness`` for GENERATIONS
generations and writes, per generation, the population as it was evaluated (``snapshot``) and,
at the end, the state of ``random`` and the file neat-python was imported from. The test imports ``fitness`` and ``snapshot`` from here to
treat the project's optimiser the same way; neither needs more than the genomes' attributes.
"""
from __future__ import annotations

import json
import math
import random
import sys


def fitness(genome) -> float:
    """A deterministic function of the genome, rounded down to whole numbers so that ties are
    common (they decide the order of members and species in both versions)."""
    weights = sum(c.weight for _key, c in sorted(genome.connections.items()) if c.enabled)
    biases = sum(n.bias for _key, n in sorted(genome.nodes.items()))
    return float(math.floor(weights - biases + 0.5 * len(genome.nodes)))


def snapshot(population: dict, species_set) -> dict:
    """Every gene of every genome and every species, in the order of their dicts (the order
    neat-python's next draws depend on)."""
    return {
        "genomes": [[key,
                     [[k, n.bias, n.response, n.activation, n.aggregation] for k, n in g.nodes.items()],
                     [[a, b, c.weight, c.enabled] for (a, b), c in g.connections.items()]]
                    for key, g in population.items()],
        "species": [[sid, s.representative.key, list(s.members)] for sid, s in species_set.species.items()],
    }


def main(neat_dir: str, config_path: str, seed: str, generations: str, out: str) -> None:
    sys.path.insert(0, neat_dir)
    import neat
    from neat.reporting import BaseReporter

    def neat_sigmoid(x):
        return 1.0 / (1.0 + math.exp(-max(-60.0, min(60.0, 4.9 * x))))

    config = neat.Config(neat.DefaultGenome, neat.DefaultReproduction, neat.DefaultSpeciesSet,
                         neat.DefaultStagnation, config_path)
    config.genome_config.add_activation("neat_sigmoid", neat_sigmoid)
    snapshots = []

    class Snapshots(BaseReporter):
        def post_evaluate(self, config, population, species, best_genome):
            snapshots.append(snapshot(population, species))

    def evaluate(genomes, config):
        for _key, genome in genomes:
            genome.fitness = fitness(genome)

    random.seed(int(seed))
    population = neat.Population(config)
    population.add_reporter(Snapshots())
    population.run(evaluate, int(generations))
    with open(out, "w") as handle:
        json.dump({"neat_file": neat.__file__, "snapshots": snapshots, "random_state": random.getstate()}, handle)


if __name__ == "__main__":
    main(*sys.argv[1:])
