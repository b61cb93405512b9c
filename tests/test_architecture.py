"""The allowed dependency graph of ``src/skincal`` (docs/design.md, "Layout"), checked on the source with ``ast``.

Every import counts, at module level and inside functions (a lazy import is still a dependency). The rules:
library packages (kinematics, skin, protocol, sim, data, calib, perception, control, hw) import neither ``cli``
nor ``workflows`` nor ``bench`` nor ``viz``; ``control`` and ``calib`` import no ``sim``; ``viz`` is imported only
by ``cli``, ``workflows`` and ``bench``; ``workflows`` and ``viz`` import neither ``cli`` nor ``bench``; ``bench``
(beside ``workflows``: it may use library packages, ``workflows`` and ``viz``) imports no ``cli``.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

import skincal

SRC = Path(skincal.__file__).resolve().parent
LIBRARY = ("kinematics", "skin", "protocol", "sim", "data", "calib", "perception", "control", "hw")
TOP = ("cli", "workflows", "bench", "viz")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """``(line, module)`` for every import in ``path``, relative imports resolved, ``from a import b`` as ``a.b``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((node.lineno, mod))
            out.extend((node.lineno, f"{mod}.{alias.name}") for alias in node.names)
    return out


def top_package(module: str) -> str | None:
    """``"sim"`` for ``skincal.sim.scene``; ``None`` outside ``skincal`` or for ``skincal`` itself."""
    parts = module.split(".")
    if parts[0] != "skincal" or len(parts) < 2:
        return None
    return parts[1]


def edges() -> list[tuple[str, str, str]]:
    """``(importer package, imported package, "file:line module")`` for every cross-package import in skincal."""
    out = []
    for path in sorted(SRC.rglob("*.py")):
        src = top_package(module_name(path))
        if src is None:
            continue
        seen = set()
        for line, mod in imported_modules(path):
            dst = top_package(mod)
            if dst is None or dst == src or not (SRC / dst).is_dir() or (line, dst) in seen:
                continue
            seen.add((line, dst))
            out.append((src, dst, f"{path.relative_to(SRC.parent)}:{line} imports {mod}"))
    return out


def violations(all_edges: list[tuple[str, str, str]]) -> list[str]:
    bad = []
    for src, dst, where in all_edges:
        if src in LIBRARY and dst in TOP:
            bad.append(f"library package {src} depends on {dst}: {where}")
        elif src in ("control", "calib") and dst == "sim":
            bad.append(f"{src} depends on sim: {where}")
        elif dst == "viz" and src not in ("cli", "workflows", "bench"):
            bad.append(f"viz imported by {src}: {where}")
        elif src in ("workflows", "bench", "viz") and dst == "cli":
            bad.append(f"{src} depends on cli: {where}")
        elif src in ("workflows", "viz") and dst == "bench":
            bad.append(f"{src} depends on bench: {where}")
    return sorted(set(bad))


def test_dependency_graph_is_the_allowed_one():
    bad = violations(edges())
    assert not bad, "forbidden imports:\n" + "\n".join(bad)


def test_every_package_is_classified():
    """A new top-level package must be placed in the graph (here and in docs/design.md) before it is used."""
    packages = {p.name for p in SRC.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert packages == set(LIBRARY) | set(TOP)


# The checker itself: it must see imports inside functions and relative ones, or it proves nothing.


@pytest.fixture
def fake_tree(tmp_path, monkeypatch):
    root = tmp_path / "skincal"
    for pkg in ("control", "sim", "viz", "cli", "workflows", "bench"):
        (root / pkg).mkdir(parents=True)
        (root / pkg / "__init__.py").write_text("")
    (root / "__init__.py").write_text("")
    monkeypatch.setattr(sys.modules[__name__], "SRC", root)
    return root


def test_checker_sees_function_level_and_relative_imports(fake_tree):
    (fake_tree / "control" / "loop.py").write_text("def run():\n    from skincal.sim.scene import Scene\n")
    (fake_tree / "control" / "play.py").write_text("from ..viz import model\n")
    (fake_tree / "sim" / "x.py").write_text("import skincal.workflows.sweep\n")
    (fake_tree / "workflows" / "ok.py").write_text("from skincal.viz.model import Recording\nfrom skincal import sim\n")
    (fake_tree / "viz" / "up.py").write_text("import skincal.cli.app\n")
    (fake_tree / "bench" / "ok.py").write_text("from skincal.workflows import sweep\nfrom skincal.viz import model\n")
    (fake_tree / "bench" / "up.py").write_text("from skincal.cli import app\n")
    (fake_tree / "workflows" / "up.py").write_text("def f():\n    import skincal.bench.table1\n")
    (fake_tree / "sim" / "y.py").write_text("from skincal.bench import avoid\n")
    bad = violations(edges())
    assert any("control depends on sim: skincal/control/loop.py:2" in b for b in bad)
    assert any("library package control depends on viz: skincal/control/play.py:1" in b for b in bad)
    assert any("library package sim depends on workflows: skincal/sim/x.py:1" in b for b in bad)
    assert any("viz depends on cli: skincal/viz/up.py:1" in b for b in bad)
    assert not any("workflows/ok.py" in b for b in bad)
    assert any("bench depends on cli: skincal/bench/up.py:1" in b for b in bad)
    assert any("workflows depends on bench: skincal/workflows/up.py:2" in b for b in bad)
    assert any("library package sim depends on bench: skincal/sim/y.py:1" in b for b in bad)
    assert not any("bench/ok.py" in b for b in bad)
