"""How a view is shown: saved to an ``.rrd``, served by rerun's web viewer on 127.0.0.1, or streamed
to a native viewer started on 127.0.0.1 (the ``rerun`` binary of the rerun-sdk wheel, run in its
own session so that it outlives the replay when asked to, and stopped by its process group).
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from imu_dcm.app.rerun_mode import check_rerun_mode, check_rerun_switch, rerun_save_path
from imu_dcm.errors import ImuDcmError, InputError
from imu_dcm.outputs import Claim, claim_output, claimed_path
from imu_dcm.viz.log import make_blueprint, new_recording, send_view
from imu_dcm.viz.view_data import ViewData

_FLUSH_TIMEOUT_S = 60.0  # a viewer that went away must not hang the replay


def save_rrd(view: ViewData, path: str | os.PathLike | Claim) -> Path:
    """Write the view (data and blueprint) to an ``.rrd`` file, atomically.

    Parameters
    ----------
    view : ViewData
    path : path-like or Claim
        Destination; must end in ``.rrd``. A path is claimed here (kind ``rrd``: new, or a
        recording this tool wrote, :func:`imu_dcm.outputs.claim_output`); a command passes the
        claim it checked before its work. Parent folders are created.

    Returns
    -------
    Path
        The file written.
    """
    claim = path if isinstance(path, Claim) else None
    target = claim.path if claim is not None else Path(path)
    if target.suffix != ".rrd":
        raise InputError(f"Expected an .rrd path, got {str(target)!r}")
    if claim is None:
        claim = claim_output(target, "rrd", what="--rerun save: file")
    check_rerun_switch(f"save:{target}")  # RERUN=off: rerun would save an empty file
    rec = new_recording(view)
    with claimed_path(claim) as tmp:
        rec.save(tmp, default_blueprint=make_blueprint(view))
        rec.send_recording_name(view.title)
        send_view(view, rec)
        rec.flush()
        rec.disconnect()
    return claim.path


def saved_line(path: str | os.PathLike) -> str:
    """The line printed after a view was saved: how to open it, with and without a display."""
    return (
        f"rerun: saved {path}; open it with: rerun {path} (without a display: rerun "
        f"--serve-web --bind 127.0.0.1 --port 9876 --web-viewer-port 9090 {path}, then "
        f"http://127.0.0.1:9090; Ctrl-C stops it; from another machine forward both ports: "
        f"ssh -L 9090:127.0.0.1:9090 -L 9876:127.0.0.1:9876 HOST)"
    )


# ------------------------------------------------------------------------------------------------
# the rerun binary (viewer / web server), always bound to 127.0.0.1


def rerun_binary() -> Path:
    """Path of the ``rerun`` executable shipped in the rerun-sdk wheel (package ``rerun_cli``)."""
    override = os.environ.get("RERUN_CLI_PATH")
    if override:
        return Path(override)
    import rerun_cli

    exe = Path(rerun_cli.__file__).with_name("rerun.exe" if sys.platform == "win32" else "rerun")
    if not exe.is_file():
        raise ImuDcmError(f"Expected the rerun binary at {exe}, got no such file")
    return exe


def _rerun_env() -> dict[str, str]:
    """Environment for the rerun binary: analytics and telemetry off (rerun skips them under CI)."""
    env = dict(os.environ)
    env.update({"CI": "1", "TELEMETRY_ENABLED": "false", "RUST_LOG": env.get("RUST_LOG", "warn")})
    return env


def free_port() -> int:
    """A TCP port of 127.0.0.1 free now (the system's choice)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Child:
    """A process started with ``os.posix_spawn`` in a new session: ``pid``, ``poll``, ``wait``.

    Unlike ``subprocess.Popen`` it does not warn when dropped while running, which is what a
    server left running for the user (``serve``/``spawn``) does on purpose.
    """

    def __init__(self, cmd: list[str], log_path: str | os.PathLike | None) -> None:
        out = str(log_path) if log_path is not None else os.devnull
        actions = [
            (os.POSIX_SPAWN_OPEN, 0, os.devnull, os.O_RDONLY, 0),
            (os.POSIX_SPAWN_OPEN, 1, out, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644),
            (os.POSIX_SPAWN_DUP2, 1, 2),
        ]
        self.pid = os.posix_spawn(cmd[0], cmd, _rerun_env(), file_actions=actions, setsid=True)
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped elsewhere
                self.returncode = -1
            else:
                if pid:
                    self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float) -> int:
        deadline = time.monotonic() + timeout
        while self.poll() is None:
            if time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(str(self.pid), timeout)
            time.sleep(0.02)
        return self.returncode


def _start(cmd: list[str], log_path: str | os.PathLike | None):
    """Start the rerun binary in its own session, output to ``log_path`` (or discarded)."""
    if hasattr(os, "posix_spawn"):
        return _Child(cmd, log_path)
    with open(log_path or os.devnull, "ab") as log:  # pragma: no cover - Windows
        return subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=_rerun_env()
        )


def _wait_for_port(
    port: int, proc, timeout_s: float, log_path: str | os.PathLike | None = None
) -> None:
    """Wait until 127.0.0.1:port accepts connections; raise if the process exits first."""
    deadline = time.monotonic() + timeout_s
    see = f" (its output: {log_path})" if log_path else ""
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(
                f"Expected rerun to listen on 127.0.0.1:{port}, "
                f"got exit code {proc.returncode}{see}"
            )
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"Expected rerun to listen on 127.0.0.1:{port} within {timeout_s} s{see}")


@dataclass(frozen=True)
class ServedViewer:
    """A ``rerun`` web-viewer server bound to 127.0.0.1.

    Attributes
    ----------
    process
        The server process (leader of its own session): ``pid``, ``poll()``, ``wait(timeout)``.
    url : str
        The web viewer, already pointed at the recording.
    grpc_url : str
        The gRPC proxy (``rerun+http://127.0.0.1:PORT/proxy``) a native viewer or SDK can use.
    grpc_port, web_port : int
        The two ports, both on 127.0.0.1.
    """

    process: object
    url: str
    grpc_url: str
    grpc_port: int
    web_port: int

    def stop(self, timeout_s: float = 5.0) -> None:
        """Terminate the server (and its process group) and wait for it."""
        if self.process.poll() is None:
            _signal_group(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                _signal_group(self.process.pid, signal.SIGKILL)
                self.process.wait(timeout_s)


def _signal_group(pid: int, sig: int) -> None:
    """Signal the process group led by ``pid`` (POSIX), or the process itself."""
    try:
        if hasattr(os, "killpg"):
            os.killpg(pid, sig)
        else:  # pragma: no cover - Windows
            os.kill(pid, sig)
    except ProcessLookupError:
        pass


def serve_rrd(
    path: str | os.PathLike | None,
    *,
    grpc_port: int | None = None,
    web_port: int | None = None,
    timeout_s: float = 20.0,
    log_path: str | os.PathLike | None = None,
    remove_after: str | os.PathLike | None = None,
) -> ServedViewer:
    """Serve an ``.rrd`` (or, with ``path=None``, a live gRPC proxy) in rerun's web viewer.

    Runs ``rerun --serve-web --bind 127.0.0.1`` (never all interfaces) in its own process group
    and returns once both ports accept connections. Stop it with :meth:`ServedViewer.stop`.

    Parameters
    ----------
    path : path-like or None
        Recording to serve; ``None`` serves an empty proxy an SDK can stream to.
    grpc_port, web_port : int, optional
        Ports on 127.0.0.1; free ports are chosen when omitted.
    timeout_s : float
        How long to wait for the ports, s.
    log_path : path-like, optional
        File receiving the server's stdout/stderr (default: discarded).
    remove_after : path-like, optional
        A folder removed when the server ends, however it ends: the server then runs under
        :mod:`imu_dcm.viz.keeper`, whose pid ``process`` is, so that ``kill PID`` stops the
        server and removes the folder (for a server left running for the user).
    """
    if path is not None and not Path(path).is_file():
        raise InputError(f"Expected an existing .rrd file, got {str(path)!r}")
    grpc_port = grpc_port or free_port()
    web_port = web_port or free_port()
    cmd = [
        str(rerun_binary()),
        "--serve-web",
        "--bind",
        "127.0.0.1",
        "--port",
        str(grpc_port),
        "--web-viewer-port",
        str(web_port),
    ]
    if path is not None:
        cmd.append(str(path))
    if remove_after is not None:
        keeper = Path(__file__).with_name("keeper.py")
        cmd = [sys.executable, str(keeper), str(remove_after), "--", *cmd]
    proc = _start(cmd, log_path)
    grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    served = ServedViewer(
        proc,
        f"http://127.0.0.1:{web_port}/?url={_quote(grpc_url)}",
        grpc_url,
        grpc_port,
        web_port,
    )
    try:
        _wait_for_port(grpc_port, proc, timeout_s, log_path)
        _wait_for_port(web_port, proc, timeout_s, log_path)
    except BaseException:
        served.stop()
        raise
    return served


def _quote(s: str) -> str:
    from urllib.parse import quote

    return quote(s, safe="")


def has_display() -> bool:
    """True when a graphical display is available (Linux: DISPLAY or WAYLAND_DISPLAY set)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True  # macOS and Windows always have a desktop session for a local user


def start_viewer(timeout_s: float = 20.0) -> tuple[object, int]:
    """Start the native viewer (the ``rerun`` binary) listening on a free port of 127.0.0.1, in
    its own session so that it outlives the caller until the user closes it, its output in a
    log file of the temporary folder; returns ``(process, port)`` once the port accepts
    connections (the recording connects to ``rerun+http://127.0.0.1:PORT/proxy``)."""
    port = free_port()
    log_path = Path(tempfile.gettempdir()) / f"imu_dcm_rerun_viewer_{port}.log"
    cmd = [str(rerun_binary()), "--bind", "127.0.0.1", "--port", str(port), "--expect-data-soon"]
    proc = _start(cmd, log_path)
    _wait_for_port(port, proc, timeout_s, log_path)
    return proc, port


def _spawn_viewer(view: ViewData, realtime: bool) -> str:
    """Start the native viewer on 127.0.0.1 (detached) and stream the view to it."""
    proc, port = start_viewer()
    rec = new_recording(view)
    rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy", default_blueprint=make_blueprint(view))
    rec.send_recording_name(view.title)
    send_view(view, rec, realtime=realtime)
    rec.flush(timeout_sec=_FLUSH_TIMEOUT_S)
    rec.disconnect()
    return f"rerun: viewer started (pid {proc.pid}, listening on 127.0.0.1:{port})"


def _safe_stem(title: str) -> str:
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", title).strip("._")
    return stem or "replay"


#: The one line a headless run prints instead of writing a view nobody asked for.
HEADLESS_HINT = (
    "rerun: no display, so no view; see it in a browser with --rerun serve (web viewer on "
    "127.0.0.1) or save it with --rerun save:F.rrd"
)


@dataclass
class ServedReplay:
    """A replay served by :func:`serve_replay`: the web viewer and the temporary folder of its
    ``.rrd`` (None when streamed). :meth:`stop` ends the server and removes the folder."""

    viewer: ServedViewer
    folder: Path | None

    @property
    def line(self) -> str:
        return f"rerun: web viewer at {self.viewer.url} (127.0.0.1 only)"

    def stop(self) -> None:
        import shutil

        self.viewer.stop()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)


def serve_replay(
    view: ViewData,
    realtime: bool = False,
    tmp_parent: str | os.PathLike | None = None,
    keep: bool = False,
) -> ServedReplay:
    """Serve a replay in rerun's web viewer on 127.0.0.1; the caller stops it.

    ``realtime``: stream to the server at the recorded speed (the URL is printed first);
    otherwise the view is saved to a temporary ``.rrd`` that :meth:`ServedReplay.stop` removes,
    in a folder made under ``tmp_parent`` (default: the system's temporary folder). ``keep``:
    the server is left running for the user, so it removes that folder itself when it ends
    (``serve_rrd``'s ``remove_after``).
    """
    if realtime:
        served = serve_rrd(None)
        try:  # Ctrl-C or an error while streaming must not leave the server running
            print(f"rerun: open {served.url} (streaming at recorded speed)", flush=True)
            rec = new_recording(view)
            rec.connect_grpc(served.grpc_url, default_blueprint=make_blueprint(view))
            rec.send_recording_name(view.title)
            send_view(view, rec, realtime=True)
            rec.flush(timeout_sec=_FLUSH_TIMEOUT_S)
            rec.disconnect()
        except BaseException:
            served.stop()
            raise
        return ServedReplay(served, None)
    folder = Path(tempfile.mkdtemp(prefix="imu_dcm_rerun_", dir=tmp_parent))
    try:
        rrd = save_rrd(view, folder / (_safe_stem(view.title) + ".rrd"))
        served = serve_rrd(rrd, remove_after=folder if keep else None)
    except BaseException:
        import shutil

        shutil.rmtree(folder, ignore_errors=True)
        raise
    return ServedReplay(served, folder)


def show_replay(
    view: ViewData,
    mode: str | None,
    save_dir: str | os.PathLike | None = None,
    realtime: bool = False,
) -> str:
    """Show a replay in rerun and return the one line to print about it.

    Parameters
    ----------
    view : ViewData
        The arrays to show.
    mode : {"spawn", "serve", "save:PATH.rrd", "off", None}
        ``"spawn"``: start the native viewer (listening on 127.0.0.1) and stream to it; needs a
        display. ``"serve"``: :func:`serve_replay`, left running (the line gives the URL and the
        pid to stop; the command line waits and stops it instead). ``"save:PATH.rrd"``: write
        the file. ``"off"``: nothing. ``None``: ``"spawn"`` when a display exists, else
        nothing at all (the line is :data:`HEADLESS_HINT`).
    save_dir : path-like, optional
        Where ``"serve"`` makes the temporary folder of its ``.rrd`` (default: the system's
        temporary folder). The headless default writes no file.
    realtime : bool
        Pace the data at the recorded speed in small chunks (for live viewing with ``"spawn"``
        and ``"serve"``; with ``"serve"`` the URL is printed before streaming). Files are
        written at full speed.

    Returns
    -------
    str
        The line to print (how to open the view); empty for ``"off"``.

    Raises
    ------
    InputError
        For an unknown mode, a ``save:`` path not ending in ``.rrd``, ``"spawn"`` without a
        display, or a mode other than ``"off"`` while ``RERUN=off`` turns rerun's SDK off
        (:func:`imu_dcm.app.rerun_mode.check_rerun_switch`; the default then shows nothing).
    """
    mode = check_rerun_mode(mode, "rerun mode")  # RERUN=off: the default shows nothing
    if mode is None:
        if not has_display():
            return HEADLESS_HINT
        mode = "spawn"
    if mode == "off":
        return ""
    target = rerun_save_path(mode)
    if target is not None:
        return saved_line(save_rrd(view, target))
    if mode == "serve":
        served = serve_replay(view, realtime, save_dir, keep=True)
        v = served.viewer
        return (
            f"rerun: web viewer at {v.url} (127.0.0.1 only; it keeps a thread busy while it "
            f"runs: stop it with: kill {v.process.pid}; from another machine forward both "
            f"ports: ssh -L {v.web_port}:127.0.0.1:{v.web_port} "
            f"-L {v.grpc_port}:127.0.0.1:{v.grpc_port} HOST)"
        )
    if not has_display():  # the one mode left: spawn
        raise InputError(
            "Expected a display (DISPLAY or WAYLAND_DISPLAY) for rerun mode 'spawn', got none; "
            "use 'serve' or 'save:PATH.rrd'"
        )
    return _spawn_viewer(view, realtime)
