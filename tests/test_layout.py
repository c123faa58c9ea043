"""The layout: imports point one way, no import circles, short functions, every module imports,
and the wheel ships two packages.

Layers (docs/design.md, "Where each concept lives"): the core maths (``so3``, the integrator and
its kernels, streaming, resampling, rest detection, metrics, Allan deviation, the pre-filter, the
reference integrators, errors, and the small helpers every layer shares: safe output, command-line
parsing) imports neither log I/O nor replay, viz, live or benchmarks; log I/O (reading and
writing every container: ``logio``, with the bag writer) imports no replay, viz or live; live
imports no replay (what both need lives below them); nothing in the shipped packages imports
``benchmarks`` (a folder of the repository, not part of the wheel) or ``tests``.

Circles: no module reaches itself through the imports of ``imu_dcm``, ``data_synth`` or
``benchmarks``, counting imports inside functions too (a lazy import defers the circle, it does
not remove it). Length: no function of the shipped packages runs over
:data:`MAX_FUNCTION_LINES` lines (``def`` to its last line), so each one holds one idea.
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
    "rates",
    "methods",
    "kernel",
    "kernel_state",
    "kernel_jit",
    "kernel_build",
    "integrate",
    "streaming",
    "resample",
    "rest",
    "rest_evidence",
    "windows",
    "stamps",
    "metrics",
    "allan",
    "prefilter",
    "reference",
    "peers",
    "errors",
    "outputs",
    "output_rule",
    "signatures",
    "app",
    "__main__",  # python -m imu_dcm: the list of commands (imports nothing of the project)
)
# the bag writer belongs to log I/O wherever it sits: imu_dcm/bag_writer.py or inside logio
LOG_IO = ("logio", "bag_writer")
UPPER = ("imu_dcm.replay", "imu_dcm.viz", "imu_dcm.live", "benchmarks")
#: The longest function the shipped packages may hold, in lines from ``def`` to its last line.
MAX_FUNCTION_LINES = 80


def _files(name: str) -> list[Path]:
    """Source files of ``imu_dcm.<name>`` (a module or every file of a package); [] if absent."""
    module, package = PACKAGE / f"{name}.py", PACKAGE / name
    if package.is_dir():
        return sorted(package.rglob("*.py"))
    return [module] if module.is_file() else []


def _module_name(path: Path, root: Path = REPO) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _import_statements(path: Path, root: Path = REPO) -> list[tuple[int, str, tuple[str, ...]]]:
    """``(line, module, names)`` per import statement of a file, at any depth, relative imports
    resolved: ``import a.b`` gives ``(line, "a.b", ())``, ``from .x import y`` gives
    ``(line, "<package>.x", ("y",))``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = _module_name(path, root).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name, ()) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join([*base, node.module] if node.module else base)
            found.append((node.lineno, mod, tuple(alias.name for alias in node.names)))
    return sorted(found)


def _imports(path: Path, root: Path = REPO) -> set[str]:
    """Every module a file imports, relative imports resolved, at any depth of the file."""
    found = set()
    for _, mod, names in _import_statements(path, root):
        found.add(mod)
        found.update(f"{mod}.{name}" for name in names)
    return found


def _import_graph(folder: Path, root: Path = REPO) -> dict[str, dict[str, int]]:
    """The modules under ``folder`` and, for each, the modules of that folder it imports, with
    the line of the first such import. An import names the most specific module it loads:
    ``from a import b`` is an import of the module ``a.b`` when there is one, else of ``a``."""
    modules = {_module_name(path, root): path for path in sorted(folder.rglob("*.py"))}

    def known(name: str) -> str | None:  # the longest prefix of a dotted name that is a module
        parts = name.split(".")
        while parts and ".".join(parts) not in modules:
            parts.pop()
        return ".".join(parts) or None

    graph: dict[str, dict[str, int]] = {}
    for name, path in modules.items():
        edges = graph.setdefault(name, {})
        for line, mod, names in _import_statements(path, root):
            for target in [known(f"{mod}.{n}") for n in names] or [known(mod)]:
                if target is not None and target != name:
                    edges.setdefault(target, line)
    return graph


def _strongly_connected(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one module, each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
                on_stack.discard(component[-1])
            if len(component) > 1:
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(components)


def _shortest_path(graph: dict[str, dict[str, int]], start: str, goal: str, inside: set[str]):
    """The shortest import path ``start -> ... -> goal`` through the modules ``inside``."""
    previous = {start: start}
    queue = [start]
    for v in queue:
        if v == goal:
            break
        for w in sorted(graph[v]):
            if w in inside and w not in previous:
                previous[w] = v
                queue.append(w)
    path = [goal]
    while path[-1] != start:
        path.append(previous[path[-1]])
    return path[::-1]


def _circles(graph: dict[str, dict[str, int]]) -> list[str]:
    """Every import circle as a readable path, one per import that lies on a circle (the
    shortest circle through it): ``a (line 3) -> b (line 9) -> a``, where ``(line n)`` is the
    line of the module on its left that imports the next one."""
    found = set()
    for component in _strongly_connected(graph):
        inside = set(component)
        for u in component:
            for v in graph[u]:
                if v in inside:
                    cycle = [u, *_shortest_path(graph, v, u, inside)[:-1]]
                    k = cycle.index(min(cycle))
                    found.add(tuple(cycle[k:] + cycle[:k]))

    def readable(c: tuple[str, ...]) -> str:
        steps = [f"{a} (line {graph[a][b]})" for a, b in zip(c, c[1:] + c[:1], strict=True)]
        return " -> ".join([*steps, c[0]])

    return [readable(c) for c in sorted(found)]


def _long_functions(files: list[Path], root: Path = REPO) -> list[str]:
    """``file:line name: n lines`` for every function or method longer than the limit."""
    long = []  # (file, line, text)
    for path in files:
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        todo = [(node, "") for node in tree.body]
        while todo:
            node, prefix = todo.pop()
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = prefix + node.name
                todo.extend((child, name + ".") for child in node.body)
                n = node.end_lineno - node.lineno + 1
                if not isinstance(node, ast.ClassDef) and n > MAX_FUNCTION_LINES:
                    where = f"{path.relative_to(root)}:{node.lineno}"
                    long.append((path, node.lineno, f"{where} {name}: {n} lines"))
            else:
                todo.extend((child, prefix) for child in ast.iter_child_nodes(node))
    return [text for _, _, text in sorted(long)]


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


def test_live_imports_no_replay():
    # live and replay are siblings: what both need (the truth slerp, the integrator, the
    # readers) lives below them, so either can change without the other
    assert _offending(_files("live"), ("imu_dcm.replay",)) == []


def test_every_module_of_imu_dcm_has_a_layer():
    # a new top-level module must be placed in a layer here, or the checks above skip it
    layered = set(CORE) | set(LOG_IO) | {m.split(".")[-1] for m in UPPER}
    top = {p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    top |= {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert sorted(top - layered) == []


def test_the_circle_finder_reports_every_circle_as_a_path(tmp_path):
    # a -> b -> c -> a through a function-level import, d <-> e through "from . import", and
    # f importing a without being on a circle
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    for name, text in {
        "__init__": "",
        "a": "from pkg import b\n",
        "b": "import os\nfrom pkg.c import thing\n",
        "c": "def f():\n    from . import a\n",
        "d": "from . import e\n",
        "e": "\n\nfrom pkg.d import x\n",
        "f": "import pkg.a\n",
    }.items():
        (pkg / f"{name}.py").write_text(text, encoding="utf-8")
    graph = _import_graph(pkg, tmp_path)
    assert _strongly_connected(graph) == [["pkg.a", "pkg.b", "pkg.c"], ["pkg.d", "pkg.e"]]
    assert _circles(graph) == [
        "pkg.a (line 1) -> pkg.b (line 2) -> pkg.c (line 2) -> pkg.a",
        "pkg.d (line 1) -> pkg.e (line 3) -> pkg.d",
    ]


def test_no_import_circles_in_the_shipped_packages():
    circles = _circles(_import_graph(PACKAGE)) + _circles(_import_graph(REPO / "data_synth"))
    assert circles == [], "\n".join(["import circles:", *circles])


def test_no_import_circles_in_benchmarks():
    circles = _circles(_import_graph(REPO / "benchmarks"))
    assert circles == [], "\n".join(["import circles:", *circles])


def test_the_length_measure_counts_from_def_to_the_last_line(tmp_path):
    def body(indent: str) -> str:
        return "".join(f"{indent}x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES - 1))

    probe = tmp_path / "probe.py"
    probe.write_text(
        f"def short():\n{body('    ')}\n\nclass C:\n    def long(self):\n{body('        ')}"
        "        return 1\n",
        encoding="utf-8",
    )
    # short: def + 79 lines = 80 (allowed); C.long: def + 79 + return = 81, nested in a class
    assert _long_functions([probe], tmp_path) == [
        f"probe.py:{MAX_FUNCTION_LINES + 4} C.long: {MAX_FUNCTION_LINES + 1} lines"
    ]


def test_no_shipped_function_runs_over_80_lines():
    files = sorted(PACKAGE.rglob("*.py")) + sorted((REPO / "data_synth").rglob("*.py"))
    long = _long_functions(files)
    assert long == [], "\n".join([f"over {MAX_FUNCTION_LINES} lines:", *long])


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
