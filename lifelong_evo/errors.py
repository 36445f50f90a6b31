"""The error a user can fix: ``python -m lifelong_evo`` prints its message as one line,
``error: ...``, and exits with status 2.

Every such error of the lifelong tools derives from ``UserError``: a message that names what was
given and what would work. ``envs.ConfigError`` and ``algorithms.UnknownAlgorithmError`` are
user errors too, but the environment and the optimisers import nothing from ``lifelong_evo``, so
they keep their own base classes and the command line catches them beside ``UserError``.
"""


class UserError(Exception):
    """A mistake in what the user gave (a path, a flag, a run directory): one line that says what to do."""
