"""Bad input never crashes: one line naming the file, line and key, exit 2, nothing written.

Run as a user would, as processes with a deadline: a hang or a segfault fails the test.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import WELDING_CELL

LAUGHS = "\n".join(
    ["name: lol", "layout: {}", "entities: {}", "campaign:", "  samplers:", "    x:", "      kind: choice", "      values:",
     '        - &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    + [f"        - &{b} [{','.join(['*' + a] * 9)}]" for a, b in zip("abcdefgh", "bcdefghi")]
) + "\n"

BOMBS = {
    "100 000 levels of nesting": ("name: x\nentities: " + "[" * 100_000 + "]" * 100_000 + "\n", "nested deeper than 100 levels"),
    "billion laughs": (LAUGHS, "expands to more than"),
    "recursive alias": ("name: &a [*a]\n", "recursive YAML alias"),
}


def cellsim(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cellsim.cli", *args], capture_output=True, text=True, timeout=timeout)


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err[:2000]
    return lines[0]


@pytest.mark.parametrize("bomb", list(BOMBS))
def test_yaml_bombs_are_one_line_in_bounded_time(tmp_path, bomb):
    text, expected = BOMBS[bomb]
    path = tmp_path / "bomb.yaml"
    path.write_text(text)
    out = tmp_path / "run"
    started = time.monotonic()
    done = cellsim("simulate", str(path), "--out", str(out), timeout=60)
    assert done.returncode == 2, done.stderr[-2000:]
    assert expected in one_line(done.stderr) and str(path) in done.stderr
    assert time.monotonic() - started < 30 and not out.exists()


def test_sigint_during_start_up_is_one_line_and_130(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cellsim.cli", "simulate", str(WELDING_CELL), "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        # interrupt while it is still starting up: once it is loading Drake (mapped into the
        # process), before it has built anything
        deadline = time.monotonic() + 60
        maps = Path(f"/proc/{proc.pid}/maps")
        while "pydrake" not in maps.read_text():
            assert time.monotonic() < deadline and proc.poll() is None, "never started loading Drake"
            time.sleep(0.001)  # polling another process's memory map: there is no event to wait on
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert one_line(err) == "cellsim: interrupted"
    assert not out.exists()
