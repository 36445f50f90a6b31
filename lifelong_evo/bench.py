"""``python -m lifelong_evo.bench``: the benchmark's entry point, a contract other tools read (its
last line is ``s_per_generation=<seconds>``); the benchmark itself is ``lifelong_evo.commands.bench``."""
from .commands.bench import main

if __name__ == "__main__":
    main()
