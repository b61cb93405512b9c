"""One table of careless and hostile command lines per ``skincal`` command (issue 27's classes of finding).

Every case must end as a one-line ``error: ...`` on stderr with exit 2: no traceback, no ``internal error``,
nothing left under the output names, every input file unchanged (``test_hostile_cases.py`` checks all of
it). ``{name}`` is a file of the ``hostile`` fixture (``conftest.py``), ``{tmp}`` the case's own empty
folder, ``{long}`` a file name longer than the file system allows. A new command gets a table here, or
``test_every_command_has_a_table`` fails.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Case:
    """One hostile command line.

    Attributes:
        argv: the arguments after ``skincal`` (formatted, then split on spaces).
        message: text the error line must contain.
        finding: issue 27's class of finding the case belongs to.
    """

    argv: str
    message: str
    finding: str


FINDINGS = (
    "special file",  # --force replaced a FIFO or device node with a regular file
    "input as output",  # an input overwritten with --force
    "internal error",  # a traceback (exit 3) instead of a usage error
    "size bound",  # no bound on a count or a size: minutes of work or gigabytes
    "absurd result",  # figures no robot can have, written as valid
    "silent accept",  # an impossible value accepted
    "too late",  # a failure found only after the work
    "messy error",  # warnings or a wrong name in the message
    "wrong file",  # a file of the wrong kind
)
"""Issue 27's classes of hostile finding (its terminal-injection and signal findings are tested with real
processes in ``tests/cli/test_cli_errors.py`` and ``tests/cli/test_cli_signals.py``)."""

NOT_A_SEED = "--seed -1: a seed is an integer >= 0"
TOO_LONG = "the file system here allows 255"

TABLES: dict[str, tuple[Case, ...]] = {
    "calibrate": (
        Case("calibrate {data} -o {fifo} --force", "is a FIFO", "special file"),
        Case("calibrate {data} -o {data} --force", "is the input", "input as output"),
        Case("calibrate {data} --links {links} -o {links} --force", "is the input", "input as output"),
        Case("calibrate {data} --seed -1 -o {tmp}/r.json", NOT_A_SEED, "internal error"),
        Case("calibrate {data} -o {tmp}/{long}.json", TOO_LONG, "too late"),
        Case("calibrate {data} -o {tmp}/no/such/r.json", "folder", "too late"),
        Case("calibrate {bomb} -o {tmp}/r.json", "refused before reading", "size bound"),
        Case("calibrate {milli_g} -o {tmp}/r.json", "it is in milli-g, not m/s^2", "absurd result"),
        Case("calibrate {empty} -o {tmp}/r.json", "not a readable HDF5 file", "wrong file"),
        Case("calibrate {result} -o {tmp}/r.json", "not a readable HDF5 file", "wrong file"),
        Case("calibrate {data} --option maxeval_static=many -o {tmp}/r.json", "maxeval_static", "silent accept"),
    ),
    "simulate": (
        Case("simulate --protocol fast -o {fifo_h5} --force", "is a FIFO", "special file"),
        Case("simulate --robot {urdf} --protocol fast -o {urdf} --force", "a dataset is an HDF5 file",
             "wrong file"),  # (refused by its suffix before the inputs are compared)
        Case("simulate --protocol fast --seed -1 -o {tmp}/s.h5", NOT_A_SEED, "internal error"),
        Case("simulate --units 100000 -o {tmp}/s.h5", "--units", "size bound"),
        Case("simulate --handheld --units 100000 -o {tmp}/s.h5", "--units", "size bound"),
        Case("simulate --handheld --units 0 -o {tmp}/s.h5", "--units", "silent accept"),
        Case("simulate --protocol fast -o {tmp}/{long}.h5", TOO_LONG, "too late"),
        Case("simulate --protocol fast -o {tmp}/s.json", ".json", "silent accept"),
    ),
    "protocol": (
        Case("protocol --robot panda -o {fifo_json} --force", "is a FIFO", "special file"),
        Case("protocol --robot {urdf} -o {urdf} --force", "unknown trajectory format", "wrong file"),
        Case("protocol --robot panda --seed -1 -o {tmp}/p.json", NOT_A_SEED, "internal error"),
        Case("protocol --robot panda --rate 1e-9 -o {tmp}/p.json", "--rate must be a sample rate of 10",
             "silent accept"),
        Case("protocol --robot panda -o {tmp}/{long}.json", TOO_LONG, "too late"),
    ),
    "export": (
        Case("export {result} -f json -o {fifo} --force", "is a FIFO", "special file"),
        Case("export {result} -f urdf --robot {urdf} -o {urdf} --force", "is the input", "input as output"),
        Case("export {result} -f urdf --robot {dup_link_urdf} -o {tmp}/e.urdf", "panda_link3", "silent accept"),
        Case("export {data} -f csv -o {tmp}/e.csv", "not a text file", "wrong file"),
    ),
    "segment": (
        Case("segment {data} -o {fifo} --force", "is a FIFO", "special file"),
        Case("segment {data} -o {data} --force", "is the input", "input as output"),
        Case("segment {data} -o {tmp}/{long}.json", TOO_LONG, "too late"),
    ),
    "report": (
        Case("report {result} --dataset {data} -o {fifo_html} --force", "is a FIFO", "special file"),
        Case("report {result} --dataset {data} -o {result} --force", "is the input", "input as output"),
        Case("report {result} --dataset {data} --format html", "html needs --out", "wrong file"),
    ),
    "evaluate": (
        Case("evaluate {data} --truth {data}", "not a text file", "wrong file"),
        Case("evaluate {result} --truth {result}", "not a readable HDF5 file", "wrong file"),
    ),
    "info": (
        Case("info {bomb}", "refused before reading", "size bound"),
        Case("info {empty}", "not a readable HDF5 file", "wrong file"),
    ),
    "import": (
        Case("import {fifo} -o {tmp}/i.h5", "is a FIFO (named pipe)", "wrong file"),
        Case("import {empty} -o {tmp}/i.h5", "cannot open the bag", "wrong file"),
    ),
    "emulate": (
        Case("emulate {data} --port 0", "--port 0", "silent accept"),
        Case("emulate {data} --port 9 --jitter nan", "--jitter", "silent accept"),
        Case("emulate {data} --port 9 --jitter inf", "--jitter", "internal error"),
        Case("emulate {data} --port 9 --duration -1", "--duration", "silent accept"),
        Case("emulate {data} --port 9 --duration nan", "--duration", "silent accept"),
        Case("emulate {data} --port 9 --drift-ppm 1e12", "--drift-ppm", "silent accept"),
        Case("emulate {data} --port 9 --drift-ppm -1e6", "--drift-ppm", "silent accept"),
        Case("emulate {data} --port 9 --drift-ppm nan", "--drift-ppm", "messy error"),
        Case("emulate {data} --port 9 --clock-offset nan", "--clock-offset", "messy error"),
        Case("emulate {data} --port 9 --clock-offset 1e300", "--clock-offset", "messy error"),
        Case("emulate {data} --port 9 --seed -1", NOT_A_SEED, "internal error"),
    ),
    "record": (
        Case("record --out {tmp}/r.h5 --port 0 --max-unit-samples 100000000000000000000", "--max-unit-samples",
             "internal error"),
        Case("record --out {tmp}/r.h5 --port 0 --flush-every 1e308", "--flush-every", "silent accept"),
        Case("record --out {tmp}/r.h5 --port 0 --duration inf", "--duration", "silent accept"),
        Case("record --out {tmp}/{long}.h5 --port 0 --duration 1", TOO_LONG, "too late"),
        Case("record --out {fifo_h5} --force --port 0 --duration 1", "is a FIFO", "special file"),
    ),
    "avoid": (
        Case("avoid --seed -1", NOT_A_SEED, "internal error"),
        Case("avoid --result {data} --duration 0.1", "not a text file", "wrong file"),
        Case("avoid --duration 0.1 --plot {fifo_png} --force", "is a FIFO", "special file"),
    ),
    "view": (
        Case("view {data} --duration 0", "not a text file", "wrong file"),
        Case("view {result} --duration -1", "--duration", "silent accept"),
    ),
    "benchmark": (
        Case("benchmark robustness --placements 0 --quick", "--placements must be at least 1", "silent accept"),
        Case("benchmark table1 --quick --json {fifo} --force", "is a FIFO", "special file"),
    ),
}
"""The tables, one per command (``skincal <command> ...``)."""

NO_TABLE = {
    "demo": "no input but its output folder: tests/cli/test_cli.py",
    "version": "takes no input",
    "ros2-play": "a ROS 2 publisher of a dataset: tests/cli/test_cli_ros2.py",
    "ros2": "ROS 2 live commands: tests/cli/test_cli_ros2.py",
}
"""Commands without a table here, each with where its hostile input is tried instead."""
