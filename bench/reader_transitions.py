"""How often one read of a measurement file enters the reader's module (the file layer's shape).

The call stack is followed with :func:`sys.setprofile`: the module at its top is a *room*, counting
only the package's own modules (a frame of numpy, pathlib or csv belongs to the package frame under
it). A call or a return that moves the top into another module starts a new *stay*; a module is
*entered* once per stay in it (its first call included). Returns into a module count, because the
reader that calls a helper in another module for every column comes back to itself each time.

    python bench/reader_transitions.py [MODULE]

reads a simulated kr16 file (30 poses, temperature and time columns) as the native CSV and through
a format file, and prints the stays, the rooms, the re-entries and the stays in MODULE (default
``kpioed_drake.files.tables``, the reader).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation.truth import SimulationOptions, simulate
from kpioed_drake.tracker.data import read_data

READER = "kpioed_drake.files.tables"
FORMAT = """\
separator: ";"
decimal: ","
length_unit: m
angle_unit: rad
joints: [J1, J2, J3, J4, J5, J6]
position: {x: X, y: Y, z: Z}
time: t
"""


def stays(read, *args) -> list[str]:
    """The package modules at the top of the call stack during ``read(*args)``, one per stay."""
    seq: list[str] = []

    def room(frame):
        while frame is not None:
            name = frame.f_globals.get("__name__", "")
            if name.startswith("kpioed_drake"):
                return name
            frame = frame.f_back
        return None

    def profile(frame, event, arg):
        if event not in ("call", "return"):
            return
        top = room(frame if event == "call" else frame.f_back)
        if top is not None and (not seq or seq[-1] != top):
            seq.append(top)

    sys.setprofile(profile)
    try:
        read(*args)
    finally:
        sys.setprofile(None)
    return seq


def sample_files(folder: Path):
    """(robot, native CSV, foreign file, format file) of simulated kr16 data in ``folder``."""
    robot = load_robot("kr16")
    q = robot.q_work + np.random.default_rng(3).uniform(-0.3, 0.3, size=(30, 6))
    table, _ = simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=1))
    native = folder / "data.csv"
    table.to_csv(native, index=False)
    lines = ["J1;J2;J3;J4;J5;J6;X;Y;Z;t"]
    for qq, e, t in zip(q, table[["x_mm", "y_mm", "z_mm"]].to_numpy() / 1000.0, table["time_s"], strict=True):
        lines.append(";".join(repr(float(v)).replace(".", ",") for v in [*qq, *e, t]))
    foreign = folder / "data.txt"
    foreign.write_text("\n".join(lines) + "\n")
    fmt = folder / "format.yaml"
    fmt.write_text(FORMAT)
    return robot, native, foreign, fmt


def report(module: str = READER) -> dict[str, tuple[int, int, int, int]]:
    """``{read: (stays, rooms, re-entries, stays in module)}`` for a native and a format-file read."""
    with tempfile.TemporaryDirectory() as tmp:
        robot, native, foreign, fmt = sample_files(Path(tmp))
        out = {}
        for name, args in (("native CSV", (native, robot)), ("format file", (foreign, robot, fmt))):
            seq = stays(read_data, *args)
            out[name] = (len(seq), len(set(seq)), len(seq) - len(set(seq)), seq.count(module))
    return out


if __name__ == "__main__":
    module = sys.argv[1] if len(sys.argv) > 1 else READER
    for name, (n, rooms, back, entered) in report(module).items():
        print(
            f"{name}: {n} stays in {rooms} modules, {back} returns to a module already left, "
            f"{module} entered {entered} times"
        )
