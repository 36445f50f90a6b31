"""The benchmark's contract at a tiny size: its last line is ``s_per_generation=<seconds>``."""
import re

import pytest

from lifelong_evo.bench import main


@pytest.mark.parametrize("argv", [
    ["--envs", "40", "--also", "20", "--steps", "3", "--eval-threads", "2"],
    ["--algo", "openai-es", "--population", "4", "--evals", "1", "--generations", "1", "--eval-threads", "2"],
])
def test_last_line_is_seconds_per_generation(argv, capsys):
    main(argv)
    lines = capsys.readouterr().out.strip().splitlines()
    assert "eval_threads=2" in lines[0]
    assert re.fullmatch(r"s_per_generation=\d+\.\d{3}", lines[-1]) and float(lines[-1].split("=")[1]) > 0
