"""The allowed dependency graph of ``src/skincal`` (docs/design.md, "Layout"), checked on the source with ``ast``.

Every import counts: at module level, inside functions (a lazy import is still a dependency) and under
``if TYPE_CHECKING`` (a type is a dependency too). The rules:

* **floors**: every package and top-level module has a floor (:data:`FLOORS`, bottom first) and imports
  only from lower floors (two packages on one floor do not import each other);
* **no cycles** between modules, lazy and type-only imports counted (:func:`cycles`);
* **no private names across modules**: ``from m import _x`` only inside ``m`` itself, in ``src`` and in
  the tests alike (tests use the public API);
* ``calib`` imports neither ``sim`` nor ``protocol`` (a calibrator needs neither the simulator nor motion
  plans), and ``control`` no ``sim``;
* ``import skincal.control`` and ``import skincal.kinematics`` load no ``h5py`` (checked in a subprocess).
* no module is longer than :data:`MAX_MODULE_LINES` (600) lines.
* every registered calibration method lives in its own module: the name ``N`` in
  :data:`skincal.calib.METHODS` is registered by ``skincal.calib.methods.N`` (``-`` spelt ``_``), with one
  ``register`` call there and none anywhere else in ``src`` (:func:`method_home_violations`).
* ``skincal --help`` and a command whose input file is missing load none of :data:`HEAVY` (NumPy, h5py,
  SciPy, MuJoCo, viser, Dask, ...; checked in a subprocess): the command answers at start-up speed.

:data:`KNOWN_VIOLATIONS` lists the few edges still to remove, each exactly, so that a new one fails.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

import skincal

SRC = Path(skincal.__file__).resolve().parent
TESTS = Path(__file__).resolve().parent

FLOORS: tuple[tuple[str, ...], ...] = (
    ("errors", "names"),  # one-line errors, the one name rule
    ("io", "parallel"),  # guarded JSON/YAML and atomic writes; the one parallel runner
    ("kinematics",),
    ("skin",),
    ("data",),  # the seam types (Dataset, results) and their files: imported by every producer
    ("protocol",),
    ("sim", "hw"),
    ("calib",),
    ("perception",),
    ("control",),
    ("viz",),
    ("workflows",),
    ("bench",),  # the benchmark harnesses: may use workflows and viz
    ("cli",),
    ("__main__",),  # python -m skincal
)
"""Packages (and top-level modules) of ``skincal`` by floor, bottom first."""

FORBIDDEN = {("calib", "sim"), ("calib", "protocol"), ("control", "sim")}
"""Downward edges that are still not allowed: (importer, imported) packages."""

KNOWN_VIOLATIONS: set[str] = set()
"""Violations still present, one entry each; delete an entry when its import is gone (the test says so)."""


def floor_of(package: str, floors: tuple[tuple[str, ...], ...] = FLOORS) -> int | None:
    for k, names in enumerate(floors):
        if package in names:
            return k
    return None


def module_name(path: Path, root: Path | None = None) -> str:
    root = SRC.parent if root is None else root
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path, root: Path | None = None) -> Iterator[tuple[int, str, str | None]]:
    """``(line, module, name)`` for every import in ``path`` (relative imports resolved): ``import a.b`` is
    ``("a.b", None)``, ``from a import b`` is ``("a", "b")``. Every import counts, wherever it stands."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = module_name(path, root)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, None
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = [part for part in package.split(".") if part]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            for alias in node.names:
                yield node.lineno, mod, alias.name


def source_modules(src: Path | None = None) -> dict[str, Path]:
    src = SRC if src is None else src
    return {module_name(p, src.parent): p for p in sorted(src.rglob("*.py"))}


def top_package(module: str) -> str | None:
    """``"sim"`` for ``skincal.sim.scene``, ``"errors"`` for ``skincal.errors``; None outside skincal."""
    parts = module.split(".")
    if parts[0] != "skincal" or len(parts) < 2:
        return None
    return parts[1]


def module_graph(src: Path | None = None) -> dict[str, set[str]]:
    """Module -> the skincal modules it imports. ``from a import b`` is an edge to ``a.b`` when that is a
    module, else to ``a``; a package's ``__init__`` run on the way to a submodule is not an edge."""
    mods = source_modules(src)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        for _, target, name in imports(path, (SRC if src is None else src).parent):
            full = f"{target}.{name}" if name else target
            dst = full if full in mods else target
            if dst in mods and dst != mod:
                graph[mod].add(dst)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))

    def visit(v: str) -> None:
        nonlocal counter
        index[v] = low[v] = counter
        counter += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def layer_violations(src: Path | None = None, floors: tuple[tuple[str, ...], ...] = FLOORS) -> list[str]:
    """Every import that goes up a floor, across one floor, to an unclassified package, or is forbidden."""
    src = SRC if src is None else src
    mods = source_modules(src)
    bad = set()
    for mod, path in mods.items():
        a = top_package(mod)
        if a is None:
            continue
        for _, target, name in imports(path, src.parent):
            imported = f"{target}.{name}" if name and target == "skincal" else target
            b = top_package(imported)
            if b is None or b == a:
                continue
            where = f"{path.relative_to(src.parent)} imports {imported}"
            fa, fb = floor_of(a, floors), floor_of(b, floors)
            if fa is None or fb is None:
                bad.add(f"unclassified package {a if fa is None else b}: {where}")
            elif (a, b) in FORBIDDEN:
                bad.add(f"{a} depends on {b}: {where}")
            elif fb > fa:
                bad.add(f"upward: {a} (floor {fa}) depends on {b} (floor {fb}): {where}")
            elif fb == fa:
                bad.add(f"same floor: {a} depends on {b}: {where}")
    return sorted(bad)


def private_imports(root: Path, files: list[Path]) -> list[str]:
    """``from m import _x`` where ``m`` is not the importing module (dunder names aside), skincal's or the tests'."""
    bad = []
    for path in files:
        here = module_name(path, root)
        for _, target, name in imports(path, root):
            if name is None or not name.startswith("_") or name.startswith("__") or target == "__future__":
                continue
            if target != here:
                bad.append(f"private name: {path.relative_to(root)} imports {name} from {target}")
    return sorted(set(bad))


def all_private_imports() -> list[str]:
    test_files = sorted(TESTS.rglob("*.py"))
    return private_imports(SRC.parent, sorted(SRC.rglob("*.py"))) + private_imports(TESTS, test_files)


def test_every_import_goes_down_a_floor():
    found = layer_violations()
    new = [v for v in found if v not in KNOWN_VIOLATIONS]
    assert not new, "forbidden imports:\n" + "\n".join(new)


def test_no_module_cycles_counting_lazy_and_type_only_imports():
    found = cycles(module_graph())
    assert not found, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in found)


def test_no_private_name_is_imported_from_another_module():
    found = all_private_imports()
    new = [v for v in found if v not in KNOWN_VIOLATIONS]
    assert not new, "private names imported across modules:\n" + "\n".join(new)


def test_known_violations_are_still_there():
    """An entry of :data:`KNOWN_VIOLATIONS` whose import is gone must be deleted (the list only shrinks)."""
    found = set(layer_violations()) | set(all_private_imports())
    stale = sorted(KNOWN_VIOLATIONS - found)
    assert not stale, "fixed, delete from KNOWN_VIOLATIONS:\n" + "\n".join(stale)


def test_every_package_has_a_floor():
    """A new top-level package or module must be placed on a floor (here and in docs/design.md) before it is used."""
    names = {p.name for p in SRC.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    names |= {p.stem for p in SRC.glob("*.py") if p.name != "__init__.py"}
    assert names == {n for floor in FLOORS for n in floor}


MAX_MODULE_LINES = 600
"""No module of ``src/skincal`` is longer than this (issue 25): a longer one holds more than one job."""


def long_modules(src: Path | None = None, limit: int = MAX_MODULE_LINES) -> list[str]:
    """``"path: N lines"`` for every module under ``src`` longer than ``limit`` lines."""
    src = SRC if src is None else src
    out = []
    for path in sorted(src.rglob("*.py")):
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > limit:
            out.append(f"{path.relative_to(src.parent)}: {n} lines")
    return out


def test_no_module_is_longer_than_600_lines():
    found = long_modules()
    assert not found, f"modules over {MAX_MODULE_LINES} lines (split them by job):\n" + "\n".join(found)


def test_checker_finds_a_long_module(tmp_path):
    root = tmp_path / "skincal"
    root.mkdir()
    (root / "short.py").write_text("x = 1\n" * MAX_MODULE_LINES)
    (root / "long.py").write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    assert long_modules(root) == [f"skincal/long.py: {MAX_MODULE_LINES + 1} lines"]


METHODS_PACKAGE = "skincal.calib.methods"
"""The home of every registered calibration method, one module per name."""


def registrations(src: Path | None = None) -> dict[str, list[str]]:
    """Module -> the method names it registers: calls ``register("name", ...)`` (or ``api.register``) in
    modules that import ``register`` (or ``api``) from ``skincal.calib.api`` or ``skincal.calib``."""
    src = SRC if src is None else src
    out: dict[str, list[str]] = {}
    for mod, path in source_modules(src).items():
        pulled = {name for _, target, name in imports(path, src.parent)
                  if target in ("skincal.calib.api", "skincal.calib") and name in ("register", "api")}  # fmt: skip
        if not pulled:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.Call) or not node.args:
                continue
            func = node.func
            called = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else None
            if called == "register" and (isinstance(func, ast.Name) or "api" in pulled):
                first = node.args[0]
                name = first.value if isinstance(first, ast.Constant) else ast.unparse(first)
                out.setdefault(mod, []).append(str(name))
    return out


def method_home_violations(names: set[str], src: Path | None = None) -> list[str]:
    """Every way the registered ``names`` break "one module per method under ``calib/methods/``"."""
    src = SRC if src is None else src
    bad = []
    homes = {f"{METHODS_PACKAGE}.{n.replace('-', '_')}": n for n in names}
    found = registrations(src)
    for mod, registered in sorted(found.items()):
        if mod not in homes:
            bad.append(f"{mod} registers {', '.join(registered)} (a method's home is {METHODS_PACKAGE}.<name>)")
        elif registered != [homes[mod]]:
            bad.append(f"{mod} registers {', '.join(registered)}, expected only {homes[mod]}")
    bad += [f"{n} is registered outside its module {mod}" for mod, n in sorted(homes.items()) if mod not in found]
    extra = {m for m in source_modules(src) if m.startswith(METHODS_PACKAGE + ".")} - set(homes)
    bad += [f"{m} is in {METHODS_PACKAGE} but registers no method" for m in sorted(extra)]
    return bad


def test_every_registered_method_lives_in_its_own_module():
    from skincal.calib import METHODS

    assert {"mle", "om", "om-joint", "mmm", "mm"} <= set(METHODS)
    found = method_home_violations(set(METHODS))
    assert not found, "methods out of their homes:\n" + "\n".join(found)


def test_checker_finds_a_method_out_of_its_home(tmp_path):
    calib = tmp_path / "skincal" / "calib"
    (calib / "methods").mkdir(parents=True)
    register = "from skincal.calib.api import register\n"
    (calib / "methods" / "om.py").write_text(register + 'register("om", 1)\n')
    (calib / "methods" / "helper.py").write_text("")
    (calib / "paper.py").write_text(register + 'register("om-joint", 2)\nregister("mm", 3)\n')
    (calib / "other.py").write_text('import atexit\natexit.register(print)\n')
    assert registrations(tmp_path / "skincal") == {"skincal.calib.methods.om": ["om"],
                                                   "skincal.calib.paper": ["om-joint", "mm"]}  # fmt: skip
    assert method_home_violations({"om", "om-joint", "mm"}, tmp_path / "skincal") == [
        "skincal.calib.paper registers om-joint, mm (a method's home is skincal.calib.methods.<name>)",
        "mm is registered outside its module skincal.calib.methods.mm",
        "om-joint is registered outside its module skincal.calib.methods.om_joint",
        "skincal.calib.methods.helper is in skincal.calib.methods but registers no method",
    ]


@pytest.mark.parametrize("package", ["skincal.control", "skincal.kinematics"])
def test_importing_the_package_loads_no_h5py(package):
    code = f"import sys, {package}; sys.exit(3 if 'h5py' in sys.modules else 0)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"import {package} loads h5py" if done.returncode == 3 else done.stderr


HEAVY = ("h5py", "mujoco", "rosbags", "viser", "dask", "distributed", "scipy", "numpy", "nlopt", "yourdfpy",
         "matplotlib", "qpsolvers", "cyclonedds")
"""Libraries the ``skincal`` command loads only for the commands that use them (issue 26: start-up under 0.3 s)."""

_RUN_COMMAND = """
import json, sys
from skincal.cli import main
code = main(sys.argv[2:])
json.dump({"code": code, "modules": sorted({m.partition(".")[0] for m in sys.modules})}, open(sys.argv[1], "w"))
"""


def command_imports(argv: list[str], cwd: Path, report: Path) -> tuple[int, set[str], str]:
    """``skincal *argv`` run in a fresh interpreter in ``cwd``: exit code, top-level modules loaded, stderr."""
    done = subprocess.run([sys.executable, "-c", _RUN_COMMAND, str(report), *argv], capture_output=True, text=True,
                          timeout=120, cwd=cwd)  # fmt: skip
    assert done.returncode == 0, done.stderr
    doc = json.loads(report.read_text())
    return doc["code"], set(doc["modules"]), done.stderr


@pytest.mark.parametrize(
    ("argv", "code"),
    [
        (["--help"], 0),
        (["benchmark", "--help"], 0),
        (["calibrate", "missing.h5", "-o", "out.json"], 2),
        (["info", "missing.h5"], 2),
        (["evaluate", "missing.json", "--truth", "missing.h5"], 2),
        (["view", "missing.json"], 2),
        (["report", "missing.json", "--dataset", "missing.h5"], 2),
    ],
)
def test_help_and_a_failing_command_load_no_heavy_library(argv, code, tmp_path):
    """``--help`` and a command whose input is missing answer before NumPy, h5py, SciPy, MuJoCo, viser, ...
    are imported (with its reader's own one-line error)."""
    got, modules, stderr = command_imports(argv, tmp_path, tmp_path / "modules.json")
    assert got == code, stderr
    assert not modules & set(HEAVY), f"skincal {' '.join(argv)} loads {sorted(modules & set(HEAVY))}"
    if code == 2:
        assert stderr.count("\n") == 1 and "no such file; cannot read the" in stderr, stderr


def test_the_import_check_sees_a_command_that_reads_a_file(tmp_path):
    """The check above proves something: a command that gets as far as its reader loads h5py and NumPy."""
    (tmp_path / "text.h5").write_text("not HDF5\n")
    got, modules, stderr = command_imports(["info", "text.h5"], tmp_path, tmp_path / "modules.json")
    assert got == 2 and "not a readable HDF5 file" in stderr, stderr
    assert {"h5py", "numpy"} <= modules


def test_the_early_file_check_says_what_the_reader_says(tmp_path):
    """The command's early check (:func:`skincal.cli.app.require_file`) and the readers refuse a missing
    dataset or result with the same line."""
    from skincal.cli.app import require_file
    from skincal.data.hdf5 import read_dataset
    from skincal.data.result import read_result
    from skincal.errors import DatasetError
    from skincal.io.files import DATASET_FILE, RESULT_FILE

    for what, reader in ((DATASET_FILE, read_dataset), (RESULT_FILE, read_result)):
        for path in (tmp_path / "missing", tmp_path):  # missing, and a folder
            with pytest.raises(DatasetError) as early:
                require_file(path, what)
            with pytest.raises(DatasetError) as late:
                reader(path)
            assert str(early.value) == str(late.value)


# The checker itself: it must see imports inside functions, under TYPE_CHECKING and relative ones, or it
# proves nothing.


@pytest.fixture
def fake_tree(tmp_path):
    root = tmp_path / "skincal"
    for pkg in ("kinematics", "control", "sim", "calib", "viz", "cli"):
        (root / pkg).mkdir(parents=True)
        (root / pkg / "__init__.py").write_text("")
    (root / "__init__.py").write_text("")
    (root / "errors.py").write_text("")
    return root


FAKE_FLOORS = (("errors",), ("kinematics",), ("sim", "calib"), ("control",), ("viz",), ("cli",))


def test_checker_sees_lazy_relative_and_type_only_imports(fake_tree):
    (fake_tree / "control" / "loop.py").write_text("def run():\n    from skincal.sim.scene import Scene\n")
    (fake_tree / "control" / "play.py").write_text("from ..viz import model\n")
    (fake_tree / "kinematics" / "x.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import skincal.control.loop\n"
    )
    (fake_tree / "sim" / "y.py").write_text("from skincal import calib\n")
    (fake_tree / "viz" / "ok.py").write_text("from skincal.control import loop\nfrom skincal import errors\n")
    bad = layer_violations(fake_tree, FAKE_FLOORS)
    assert any("control depends on sim: skincal/control/loop.py" in b for b in bad)
    assert any("upward: control (floor 3) depends on viz (floor 4): skincal/control/play.py" in b for b in bad)
    assert any("upward: kinematics (floor 1) depends on control" in b for b in bad)
    assert any("same floor: sim depends on calib: skincal/sim/y.py" in b for b in bad)
    assert not any("viz/ok.py" in b for b in bad)


def test_checker_finds_cycles_through_lazy_and_type_only_imports(fake_tree):
    (fake_tree / "sim" / "a.py").write_text("def f():\n    from skincal.sim.b import g\n")
    (fake_tree / "sim" / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from skincal.sim.a import f\n"
    )
    (fake_tree / "sim" / "c.py").write_text("from skincal.sim import a\n")
    assert cycles(module_graph(fake_tree)) == [["skincal.sim.a", "skincal.sim.b"]]


def test_checker_finds_private_names(tmp_path):
    (tmp_path / "m.py").write_text(
        textwrap.dedent("""
            from __future__ import annotations
            from skincal.kinematics.urdf import _parse
            from skincal.kinematics import __doc__
            from .m import _self
        """)
    )
    found = private_imports(tmp_path, [tmp_path / "m.py"])
    assert found == ["private name: m.py imports _parse from skincal.kinematics.urdf"]
