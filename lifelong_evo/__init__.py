"""lifelong-evo: lifelong evolution of swarm controllers on a batched torch foraging arena."""
__version__ = "0.1.0"
