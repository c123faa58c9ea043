"""Every shell example of the README and of docs/*.md runs, as printed, on a fresh copy of the repo.

Each ```bash (or ```sh / ```shell) block is one test, named by its file and line. The block runs
as one bash script (``set -eo pipefail``) in a fresh copy of the repository's files (the files git
tracks or would track; no ``.git``; a plain copy when there is no git checkout), with ``python``
being the Python that runs these tests, ``CI=true``, no display, and a timeout; it must exit 0.

A page that holds ```python blocks is also one test (``test_page_runs_in_order``): every block of
the page, shell and Python, runs in the page's order in one fresh copy, as a reader working down
the page would run them (a Python block sees the files the shell blocks above it wrote).

Not run, each reported as a skip with its reason:

- a block whose line above (blank lines aside) is ``<!-- needs: WHAT -->``: it needs a display, a
  server, a network peer or a long run (say which). ```console and ```text blocks are transcripts
  and never run;
- ``pip install …`` (this test runs inside the environment those lines install; a line
  ``pip install … && CMD`` runs ``CMD``) and ``python -m pytest`` (the suite that holds this test;
  CI runs it).

Every copy sits at the same path with the files' own times, and numba's cache lives beside it for
the whole session, so the integrator kernel compiles once, not once per block.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = ("README.md", *sorted(f"docs/{p.name}" for p in (REPO / "docs").glob("*.md")))
SHELLS = {"bash", "sh", "shell"}
FENCE = re.compile(r"^(`{3,}|~{3,})\s*([\w+-]*)")
NEEDS = re.compile(r"^<!--\s*needs:\s*(.*?)\s*-->$")
PIP = re.compile(r"^(python3?\s+-m\s+)?pip3?\s+install\b")
PYTEST = re.compile(r"\bpython3?\s+-m\s+pytest\b")
TIMEOUT_S = 240
IGNORED = shutil.ignore_patterns(
    ".git",
    "__pycache__",
    "*.egg-info",
    ".pytest_cache",
    ".hypothesis",
    ".ruff_cache",
    "build",
    "node_modules",
    "out",
)


@dataclass(frozen=True)
class Example:
    where: str  # "docs/replay.md:12", the line of the opening fence
    script: str  # what runs; empty when nothing does
    skip: str  # why it does not run; empty when it runs
    lang: str = "bash"  # "bash" or "python"


def _logical_lines(body: list[str]) -> list[str]:
    """The block's commands: a line ending in ``\\``, ``|``, ``&&`` or ``||`` continues."""
    out: list[str] = []
    cont = False
    for line in body:
        if cont:
            out[-1] += "\n" + line
        else:
            out.append(line)
        cont = line.rstrip().endswith(("\\", "|", "&&", "||"))
    return out


def _runnable(command: str) -> tuple[str, str]:
    """(what runs, why part of it does not) for one logical line; it keeps its indentation."""
    line = text = command.strip()
    if PIP.match(text):
        _, sep, rest = text.partition("&&")
        if not sep:
            return (
                "",
                f"`{line}`: pip install is not re-run (the tests run in the installed environment)",
            )
        command = text = rest.strip()
    if PYTEST.search(text):
        return "", f"`{line}`: the test suite itself is not re-run from here (CI runs it)"
    return command, ""


def _examples(page: str) -> list[Example]:
    lines = (REPO / page).read_text(encoding="utf-8").splitlines()
    found: list[Example] = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        end = next(
            (j for j in range(i + 1, len(lines)) if lines[j].startswith(m.group(1))), len(lines)
        )
        if m.group(2) in SHELLS:
            found += _block(page, i, lines, lines[i + 1 : end])
        elif m.group(2) == "python":
            found.append(_python_block(page, i, lines, lines[i + 1 : end]))
        i = end + 1
    return found


def _python_block(page: str, i: int, lines: list[str], body: list[str]) -> Example:
    where = f"{page}:{i + 1}"
    above = next((x.strip() for x in reversed(lines[:i]) if x.strip()), "")
    needs = NEEDS.match(above)
    if needs:
        return Example(where, "", f"{where} needs {needs.group(1)}", "python")
    return Example(where, "\n".join(body) + "\n", "", "python")


def _block(page: str, i: int, lines: list[str], body: list[str]) -> list[Example]:
    where = f"{page}:{i + 1}"
    above = next((x.strip() for x in reversed(lines[:i]) if x.strip()), "")
    needs = NEEDS.match(above)
    if needs:
        return [Example(where, "", f"{where} needs {needs.group(1)}")]
    kept, dropped = [], []
    for command in _logical_lines(body):
        run, why = _runnable(command)
        kept.append(run)
        if why:
            dropped.append(why)
    out = [Example(where, "\n".join(kept), "")] if any(k.strip() for k in kept) else []
    return out + [
        Example(f"{where} (not run {k + 1})", "", f"{where}: {why}")
        for k, why in enumerate(dropped)
    ]


PAGE_EXAMPLES = {page: _examples(page) for page in PAGES}
EXAMPLES = [e for page in PAGES for e in PAGE_EXAMPLES[page] if e.lang == "bash"]
#: Pages with Python blocks: each runs as a whole, in order (module docstring).
PYTHON_PAGES = [p for p in PAGES if any(e.lang == "python" for e in PAGE_EXAMPLES[p])]


def _source_files() -> list[str] | None:
    """The repository's files as a clone would hold them (plus new ones not ignored), or None."""
    try:
        proc = subprocess.run(
            [
                "git",
                "-C",
                str(REPO),
                "ls-files",
                "-z",
                "--cached",
                "--others",
                "--exclude-standard",
            ],
            capture_output=True,
            check=True,
            timeout=60,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    names = [n for n in proc.stdout.decode("utf-8").split("\0") if n]
    return names or None


@pytest.fixture(scope="session")
def workspace(tmp_path_factory) -> Path:
    """A session folder: ``repo/`` (remade per example), ``bin/python``, numba's cache."""
    base = tmp_path_factory.mktemp("doc_examples")
    (base / "bin").mkdir()
    for name in ("python", "python3"):
        shim = base / "bin" / name
        shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n', encoding="utf-8")
        shim.chmod(0o755)
    (base / "numba_cache").mkdir()
    return base


def _fresh_copy(base: Path) -> Path:
    dest = base / "repo"
    if dest.exists():
        shutil.rmtree(dest)
    names = _source_files()
    if names is None:
        shutil.copytree(REPO, dest, ignore=IGNORED, symlinks=True)
        return dest
    for name in names:
        src = REPO / name
        if src.is_file() or src.is_symlink():  # a deleted, not yet committed file is skipped
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name, follow_symlinks=False)
    return dest


def _env(base: Path, repo: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(
        CI="true",
        PYTHONPATH=str(repo),
        NUMBA_CACHE_DIR=str(base / "numba_cache"),
        MPLBACKEND="Agg",
        PATH=os.pathsep.join([str(base / "bin"), str(Path(sys.executable).parent), env["PATH"]]),
    )
    return env


def _run(workspace: Path, repo: Path, example: Example) -> tuple[int, str]:
    """Run one block in ``repo`` (a Python block from a file beside the copy): (exit, output)."""
    if example.lang == "python":
        script = workspace / "block.py"
        script.write_text(example.script, encoding="utf-8")
        argv = [sys.executable, str(script)]
    else:
        argv = ["bash", "-c", "set -eo pipefail\n" + example.script]
    proc = subprocess.Popen(
        argv,
        cwd=repo,
        env=_env(workspace, repo),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        out, _ = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"{example.where}: still running after {TIMEOUT_S} s\n{out[-3000:]}")
    finally:
        with contextlib.suppress(ProcessLookupError):  # what the block left running, if anything
            os.killpg(proc.pid, signal.SIGKILL)
    return proc.returncode, out


@pytest.mark.slow
@pytest.mark.parametrize("example", EXAMPLES, ids=[e.where for e in EXAMPLES])
def test_shell_example_runs(example: Example, workspace: Path):
    if example.skip:
        pytest.skip(example.skip)
    repo = _fresh_copy(workspace)
    code, out = _run(workspace, repo, example)
    assert code == 0, f"{example.where}: exit {code}\n{example.script}\n{out[-3000:]}"


@pytest.mark.slow
@pytest.mark.parametrize("page", PYTHON_PAGES)
def test_page_runs_in_order(page: str, workspace: Path):
    repo = _fresh_copy(workspace)
    ran = 0
    for example in PAGE_EXAMPLES[page]:
        if example.skip or not example.script.strip():
            continue
        code, out = _run(workspace, repo, example)
        assert code == 0, (
            f"{example.where} (after the blocks above it): exit {code}\n{example.script}\n"
            f"{out[-3000:]}"
        )
        ran += 1
    assert ran, f"{page}: no block ran"


def test_examples_were_found():
    # The README's quick start alone holds two commands; a parser that finds nothing passes nothing.
    where = {e.where.split(" ")[0] for e in EXAMPLES}
    assert any(w.startswith("README.md:") for w in where), where
    assert len([e for e in EXAMPLES if not e.skip]) >= 5, EXAMPLES
    # the README's usage block is Python: the page test runs it
    assert "README.md" in PYTHON_PAGES, PYTHON_PAGES


LINK = re.compile(r"\]\(([^)\s]+)\)")


def _anchors(page: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    lines = page.read_text(encoding="utf-8").splitlines()
    heads = [x.lstrip("#").strip().lower() for x in lines if x.startswith("#")]
    return {re.sub(r"[^\w\- ]", "", h).replace(" ", "-") for h in heads}


@pytest.mark.parametrize("page", PAGES)
def test_relative_links_resolve(page: str):
    # A page moved or a heading renamed must not leave a link pointing nowhere.
    source = REPO / page
    broken = []
    for target in LINK.findall(source.read_text(encoding="utf-8")):
        if re.match(r"^[a-z]+:", target):
            continue  # https:, mailto:
        path, _, anchor = target.partition("#")
        dest = (source.parent / path).resolve() if path else source
        if not dest.exists() or (anchor and dest.suffix == ".md" and anchor not in _anchors(dest)):
            broken.append(target)
    assert not broken, f"{page}: links to nothing: {broken}"
