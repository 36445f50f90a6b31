"""The commands: every verb of ``python -m lifelong_evo`` (``cli.VERBS``), the sweep and its Ray
driver, the tables, figures and recordings, and the benchmark. They use the run core (the
``lifelong_evo`` modules beside this folder), which never imports them."""
