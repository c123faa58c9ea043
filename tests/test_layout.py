"""The layout: imports point one way, every module imports, and the wheel ships two packages.

Layers (docs/design.md, "Where each concept lives"): the core maths (``so3``, the integrator and
its kernels, streaming, rest detection, metrics, Allan deviation, the pre-filter, the reference
integrators, errors) imports neither log I/O nor replay, viz, live or benchmarks; log I/O
imports no replay, viz or live; nothing in the shipped packages imports ``benchmarks`` (a
folder of the repository, not part of the wheel) or ``tests``.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import data_synth
import imu_dcm

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "imu_dcm"

CORE = (
    "so3",
    "kernel",
    "scan",
    "integrate",
    "streaming",
    "rest",
    "metrics",
    "allan",
    "prefilter",
    "reference",
    "errors",
)
LOG_IO = ("logio", "bag_writer")
UPPER = ("imu_dcm.replay", "imu_dcm.viz", "imu_dcm.live", "benchmarks")


def _files(name: str) -> list[Path]:
    """Source files of ``imu_dcm.<name>`` (a module or every file of a package); [] if absent."""
    module, package = PACKAGE / f"{name}.py", PACKAGE / name
    if package.is_dir():
        return sorted(package.rglob("*.py"))
    return [module] if module.is_file() else []


def _module_name(path: Path, root: Path = REPO) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, root: Path = REPO) -> set[str]:
    """Every module a file imports, relative imports resolved, at any depth of the file."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = _module_name(path, root).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join([*base, node.module] if node.module else base)
            found.add(mod)
            found.update(f"{mod}.{alias.name}" for alias in node.names)
    return found


def _offending(files: list[Path], forbidden: tuple[str, ...], root: Path = REPO) -> list[str]:
    bad = []
    for path in files:
        for mod in sorted(_imports(path, root)):
            if any(mod == f or mod.startswith(f + ".") for f in forbidden):
                bad.append(f"{path.relative_to(root)} imports {mod}")
    return bad


def test_the_import_walk_sees_every_kind_of_import(tmp_path):
    # The walk must see imports inside functions and resolve relative ones, or the checks below
    # could pass on a module that imports upwards lazily.
    assert "imu_dcm.errors" in _imports(PACKAGE / "prefilter" / "config.py")
    fake = tmp_path / "imu_dcm" / "prefilter" / "probe.py"
    fake.parent.mkdir(parents=True)
    fake.write_text(
        "def f():\n    from ..replay import core\n    import benchmarks.stability\n",
        encoding="utf-8",
    )
    found = _imports(fake, tmp_path)
    assert {"imu_dcm.replay", "imu_dcm.replay.core", "benchmarks.stability"} <= found
    assert len(_offending([fake], UPPER, tmp_path)) == 3


def test_core_imports_no_log_io_replay_viz_live_or_benchmarks():
    files = [f for name in CORE for f in _files(name)]
    # the core is there (a renamed module must be renamed here too)
    for name in ("so3", "integrate", "rest", "metrics", "allan", "prefilter", "reference"):
        assert _files(name), name
    forbidden = UPPER + tuple(f"imu_dcm.{m}" for m in LOG_IO) + ("data_synth",)
    assert _offending(files, forbidden) == []


def test_log_io_imports_no_replay_viz_or_live():
    files = [f for name in LOG_IO for f in _files(name)]
    assert _offending(files, UPPER) == []


def test_shipped_packages_import_no_benchmarks_or_tests():
    files = sorted(PACKAGE.rglob("*.py")) + sorted((REPO / "data_synth").rglob("*.py"))
    assert _offending(files, ("benchmarks", "tests", "conftest")) == []
    # and the tests themselves use the packages only, never the benchmark folder
    assert _offending(sorted((REPO / "tests").glob("*.py")), ("benchmarks",)) == []


def test_every_module_imports():
    names = []
    for pkg in (imu_dcm, data_synth):
        for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
            names.append(info.name)
            importlib.import_module(info.name)
    assert "imu_dcm.prefilter.batch" in names and "imu_dcm.viz.viewer" in names


def test_public_names_stay_where_callers_import_them():
    from imu_dcm import prefilter, rest, viz
    from imu_dcm.replay import bias

    for name in (
        "prefilter",
        "PrefilterConfig",
        "StreamingRateFilter",
        "euler_prefilter",
        "estimate_noise_from_rest",
        "estimate_noise_from_spectrum",
    ):
        assert hasattr(prefilter, name), name
    for name in ("ViewData", "save_rrd", "serve_rrd", "show_replay", "send_view", "ENTITY"):
        assert hasattr(viz, name), name
    # one rest detector: the bias module re-exports it, it does not redefine it
    assert bias.detect_rest is rest.detect_rest and bias.RestConfig is rest.RestConfig


@pytest.mark.slow
def test_wheel_ships_imu_dcm_and_data_synth_only(tmp_path):
    # Build from a copy, so the source tree gets no build/ or egg-info. pip's isolated build
    # fetches setuptools from the package index; without one the test cannot run.
    src = tmp_path / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(REPO / name, src / name)
    for name in ("imu_dcm", "data_synth", "benchmarks"):
        shutil.copytree(REPO / name, src / name, ignore=ignore)
    dist = tmp_path / "dist"
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "-w", str(dist), "-q"],
        cwd=src,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    if proc.returncode != 0 and any(
        s in proc.stderr for s in ("No matching distribution", "NewConnectionError", "Network")
    ):
        pytest.skip(f"no package index to fetch the build backend: {proc.stderr[-300:]}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    (wheel,) = dist.glob("imu_dcm-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        meta = z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    top = {n.split("/")[0] for n in names if ".dist-info/" not in n}
    assert top == {"imu_dcm", "data_synth"}
    # every subpackage made it in, not only the top-level ones
    for path in (
        "imu_dcm/prefilter/batch.py",
        "imu_dcm/viz/viewer.py",
        "imu_dcm/replay/core.py",
        "data_synth/stability/steps.py",
        "imu_dcm/rest.py",
        "imu_dcm/reference.py",
    ):
        assert path in names, path
    # the license as an SPDX expression, its file shipped (no deprecated license table)
    assert "License-Expression: MIT" in meta
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
