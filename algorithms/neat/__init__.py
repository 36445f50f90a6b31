"""NEAT (neat-python 2.0, with neat-python 0.92's genetics or 2.0's) behind the ask/tell interface.

One module per part; each imports only the parts above it in this list:

``speciation``  genetic distances computed as tensors, bit for bit neat-python's, and the
                speciation on them
``genetics``    the choice of genetics (``genetics_version``) and neat-python 0.92's genetics on
                2.0's classes
``network``     genomes as one batched torch network (``compile_genomes``: ``layout_genomes``,
                then ``fill_tensors``) and the paper's activation
``config``      the paper's NEAT table (``config.ini``) as a ``neat.Config``
``state``       NEAT's state as JSON for checkpoints (no pickle)
``export``      exported controllers back as policies
``optimizer``   ``NeatOptimizer``: ask/tell, the genetic-distance regulariser, checkpoints, export
``graph``       an exported genome as a drawing shows it, against a reference, by the regulariser's measure
"""
from __future__ import annotations

from .optimizer import NeatOptimizer, NeatOptions

__all__ = ["NeatOptimizer", "NeatOptions"]
