"""The analysis of finished runs, usable from Python without the command line: reading them
(through ``lifelong_evo.runs``), the statistics over seeds (``statistics``), the tables
(``tables``, ``comparison``, ``model_specific``, ``report``) and the figures (``figures``).
The verbs ``compare`` and ``plot`` only parse their options and call these; the same call gives
the same tables, e.g. in a notebook::

    from lifelong_evo.analysis.comparison import comparison
    print(comparison(["docs/data/paper-genetics"]).markdown)   # what `compare` prints

``examples/analysis.py`` shows more. Nothing here imports a command, and nothing here writes
into a run directory.
"""
