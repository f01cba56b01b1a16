"""The loop the hand-made mutant tools share (cascade_mutants.py, bridge_mutants.py): each mutant replaces one
piece of code in a scratch checkout, the tests that cover it run there, and the file is put back; one line per
mutant: killed, SURVIVED, did not compile, or not applied (its code is not there once, as written).
"""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
from typing import NamedTuple


class Mutant(NamedTuple):
    path: str
    code: str
    mutant: str
    breaks: str
    #: the shell command of the tests that cover it, run in the checkout ({python}: this interpreter)
    tests: str


#: What a compiler (rustc, cargo) or Python's own parser says of code that does not build.
NOT_BUILT = ("error[", "could not compile", "SyntaxError", "IndentationError")


def run_tests(command: str, root: pathlib.Path, timeout: float) -> tuple[int | None, str]:
    """(exit code, output) of ``command`` run in ``root`` with its python/ first on PYTHONPATH (exit code
    None: it ran past ``timeout`` s, and its process group, nodes it started included, was killed)."""
    env = dict(os.environ, PYTHONPATH=str(root / "python"), PYTHONDONTWRITEBYTECODE="1")
    command = command.replace("{python}", sys.executable)
    pipe = subprocess.PIPE
    process = subprocess.Popen(
        command, shell=True, cwd=root, env=env, stdout=pipe, stderr=subprocess.STDOUT, text=True, start_new_session=True
    )
    try:
        out, _ = process.communicate(timeout=timeout)
        code: int | None = process.returncode
    except subprocess.TimeoutExpired:
        code = None
    # whatever the tests left running (a node a failed test did not stop) goes with the group
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    if code is None:
        out, _ = process.communicate()
    return code, out


def verdict(code: int | None, out: str) -> str:
    if any(mark in out for mark in NOT_BUILT):
        return "did not compile"
    if code is None:
        return "killed (the tests ran past their timeout)"
    return "killed" if code != 0 else "SURVIVED"


def run(root: pathlib.Path, mutants: list[Mutant], timeout: float = 900.0, log: pathlib.Path | None = None) -> list[str]:
    """Applies each mutant alone in ``root``, runs its tests, puts the file back; prints and returns each
    mutant's line (``path | what it breaks | verdict``). ``log``: the failing tests' output is appended there."""
    lines = []
    for m in mutants:
        f = root / m.path
        text = f.read_text()
        if text.count(m.code) != 1:
            result = "not applied (the code changed)"
        else:
            f.write_text(text.replace(m.code, m.mutant, 1))
            try:
                code, out = run_tests(m.tests, root, timeout)
            finally:
                f.write_text(text)
            result = verdict(code, out)
            if log is not None:
                with log.open("a") as sink:
                    sink.write(f"=== {m.path} | {m.breaks} | {result}\n{out[-4000:]}\n")
        line = f"{m.path} | {m.breaks} | {result}"
        print(line, flush=True)
        lines.append(line)
    return lines
