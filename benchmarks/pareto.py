"""Speed against accuracy: every imu_dcm method and every peer, same run, same samples.

For each scene and sample rate, every method integrates the exact body rates ``omega_b(t_k)`` of
a ground-truth trajectory (``data_synth``) from the true initial attitude; its figure of merit is
the **max total attitude error** against the truth over all samples (deg), and its cost is the
**median time per gyro sample** (ns) over interleaved rounds after a warm-up, on one BLAS
thread (:mod:`benchmarks.timing`): wall time by default, or the process's CPU time
(``clock="cpu"``) on a shared machine. Speed ratios are against the plain DCM loop of
Xiaoliang (2014) (``reference_loop``) measured in the same rounds.

Scenes (:data:`SCENES`): the heavy top of Xiaoliang (2014) (cusp motion) over 1.2 s and 10 s,
pure coning (β = 10°, 5 Hz, closed form), and the free box near its intermediate axis
(ω0 = (0.05, 3, 0.05) rad/s, one flip in 10 s).

Methods (:func:`method_cases`): ``imu_dcm.integrate`` with every method (batch), the streaming
``imu_dcm.DcmIntegrator`` per sample (``update``) and in blocks (``update_many``) when present,
and the peers of :mod:`benchmarks.peers`.

Conventions (docs/design.md): quaternions ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world;
``omega_b`` body rate in body axes, rad/s; times ``t_s`` in seconds.
"""

from __future__ import annotations

import platform
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

import imu_dcm
from benchmarks.peers import PEERS
from benchmarks.timing import interleaved_medians
from imu_dcm.metrics import attitude_error_deg
from imu_dcm.outputs import save_figure

__all__ = [
    "FULL_RATES_HZ",
    "QUICK_RATES_HZ",
    "REFERENCE",
    "SCENES",
    "Case",
    "Measurement",
    "Scene",
    "convergence",
    "measure",
    "method_cases",
    "peer_versions",
    "plot_convergence",
    "plot_pareto",
    "results_markdown",
]

FULL_RATES_HZ = (100.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0)
QUICK_RATES_HZ = (100.0, 1000.0, 5000.0)
CONVERGENCE_RATES_HZ = (50.0, 100.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0, 10000.0, 20000.0)

#: Name of the case every speed ratio is taken against (measured in the same rounds).
REFERENCE = "reference_loop"


@dataclass(frozen=True)
class Scene:
    """A ground-truth scene: ``make()`` returns a ``data_synth`` trajectory of ``duration_s``."""

    key: str
    title: str
    duration_s: float
    make: Callable[[], object]


def _heavy_top(duration_s: float) -> Callable[[], object]:
    def make():
        import data_synth

        return data_synth.simulate("heavy-top", duration_s=duration_s, motion="cusp")

    return make


def _coning(duration_s: float) -> Callable[[], object]:
    def make():
        import data_synth

        return data_synth.simulate(
            "coning", duration_s=duration_s, half_angle_deg=10.0, freq_hz=5.0
        )

    return make


def _free_box(duration_s: float) -> Callable[[], object]:
    def make():
        import data_synth

        return data_synth.simulate("free-body", duration_s=duration_s, case="intermediate")

    return make


SCENES = (
    Scene("heavy_top_1.2s", "heavy top, cusp, 1.2 s", 1.2, _heavy_top(1.2)),
    Scene("heavy_top_10s", "heavy top, cusp, 10 s", 10.0, _heavy_top(10.0)),
    Scene("coning", "pure coning, β = 10°, 5 Hz, 2 s", 2.0, _coning(2.0)),
    Scene("free_box", "free box, intermediate axis, 10 s", 10.0, _free_box(10.0)),
)


# ----------------------------------------------------------------------------------------------
# Methods
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One method under test: ``fn(omega_b (N, 3), t_s (N,), q0 (4,)) -> q_w_b (N, 4)`` xyzw.

    ``family`` is ``"batch"``, ``"streaming"`` (imu_dcm) or ``"peer"``; ``order`` its accuracy
    order as text.
    """

    name: str
    fn: Callable[[NDArray, NDArray, NDArray], NDArray]
    family: str
    description: str
    order: str
    #: ``"rate"``: fed ``omega_b (N, 3)``; ``"delta"``: fed delta angles ``(N - 1, 3)``, rad.
    input: str = "rate"
    #: Stamps the case reports: every ``stride``-th (delta-angle sets of 2 or 3 intervals).
    stride: int = 1


_ORDER = {
    "start": "1",
    "end": "1",
    "trapezoid": "2",
    "coning": "2",
    "magnus4": "4",
    "rotvec_sum": "none (Xiaoliang 2014, eq. 13)",
}


def _batch(method: str) -> Callable:
    def fn(omega_b, t_s, q0):
        if method == "rotvec_sum":  # deliberately measured: silence its "wrong method" warning
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", imu_dcm.ImuDcmWarning)
                return imu_dcm.integrate(omega_b, t_s, q0, method).as_quat()
        return imu_dcm.integrate(omega_b, t_s, q0, method).as_quat()

    return fn


def _integrator_class():
    """``imu_dcm.DcmIntegrator`` (or from ``imu_dcm.integrator.streaming`` if not re-exported),
    else None."""
    cls = getattr(imu_dcm, "DcmIntegrator", None)
    if cls is None:
        try:
            from imu_dcm.integrator.streaming import DcmIntegrator as cls
        except ImportError:
            return None
    return cls


def _report_index(method: str, n: int) -> NDArray:
    """Index of the stamp whose attitude ``DcmIntegrator`` returns after each of ``n`` samples.

    Found by probing the integrator with 8 samples (``DcmIntegrator.t_s`` after each update):
    methods without look-ahead report the newest stamp; ``magnus4`` reports one stamp late once
    its 4-sample stencil is full and ``t_s[0]`` before. Beyond the probe the lag is constant.
    """
    k = min(n, 8)
    integ = _integrator_class()([0.0, 0.0, 0.0, 1.0], method)
    idx = []
    for j in range(k):
        integ.update([0.0, 0.0, 0.1], float(j))
        idx.append(round(integ.t_s))
    lag = k - 1 - idx[-1]
    return np.concatenate([np.array(idx, dtype=int), np.arange(k, n) - lag])


def _place(q_rows: NDArray, idx: NDArray, q_last: NDArray, n: int) -> NDArray:
    """(n, 4) attitudes by stamp; stamps a streaming run never reported are NaN rows."""
    out = np.full((n, 4), np.nan)
    out[idx] = q_rows  # later reports of a stamp overwrite earlier ones
    out[-1] = q_last
    return out


def _streaming_per_sample(method: str) -> Callable:
    """``DcmIntegrator.update`` once per sample, attitude read after each (a live filter).

    Row ``k`` of the output is the attitude reported for ``t_s[k]`` (``magnus4`` reports one
    stamp late; :meth:`finish` supplies the last); stamps never reported are NaN rows.
    """

    def fn(omega_b, t_s, q0):
        integ = _integrator_class()(q0, method)
        update = integ.update
        out = [update(w, t) for w, t in zip(omega_b, t_s.tolist(), strict=False)]
        return _place(np.asarray(out), _report_index(method, len(t_s)), integ.finish(), len(t_s))

    return fn


def _streaming_blocks(method: str, block: int = 256) -> Callable:
    """``DcmIntegrator.update_many`` on blocks of ``block`` samples (a driver reading buffers)."""

    def fn(omega_b, t_s, q0):
        integ = _integrator_class()(q0, method)
        out = [
            integ.update_many(omega_b[s : s + block], t_s[s : s + block]).as_quat()
            for s in range(0, len(t_s), block)
        ]
        return _place(
            np.concatenate(out), _report_index(method, len(t_s)), integ.finish(), len(t_s)
        )

    return fn


def _delta(method: str) -> Callable:
    """``imu_dcm.integrate_delta`` on exact delta angles; rows at stamps it does not report are
    NaN (two- and three-sample sets report every 2nd / 3rd stamp; three-sample runs on the
    longest prefix with a multiple of 3 intervals)."""
    m = _DELTA_STRIDE.get(method, 1)

    def fn(dtheta_b, t_s, q0):
        n = len(dtheta_b) - len(dtheta_b) % m
        q = imu_dcm.integrate_delta(dtheta_b[:n], t_s[: n + 1], q0, method).as_quat()
        out = np.full((len(t_s), 4), np.nan)
        out[: n + 1 : m] = q
        return out

    return fn


_DELTA_STRIDE = {"two_sample": 2, "three_sample": 3}


def method_cases(streaming: bool = True) -> list[Case]:
    """Every imu_dcm method (batch; streaming when ``imu_dcm.DcmIntegrator`` exists) and peer."""
    cases = [
        Case(
            f"batch_{m}", _batch(m), "batch", f"imu_dcm.integrate(method={m!r})", _ORDER.get(m, "?")
        )
        for m in imu_dcm.METHODS
    ]
    if streaming and _integrator_class() is not None:
        # (name prefix, callable of a method, description) per streaming form
        forms = [("stream_", _streaming_per_sample, "DcmIntegrator({!r}).update per sample")]
        if hasattr(_integrator_class(), "update_many"):
            many = "DcmIntegrator({!r}).update_many, blocks of 256"
            forms.append(("stream_many_", _streaming_blocks, many))
        cases += [
            Case(f"{prefix}{m}", make(m), "streaming", text.format(m), _ORDER.get(m, "?"))
            for prefix, make, text in forms
            for m in _streaming_methods()
        ]
    for m in getattr(imu_dcm, "DELTA_METHODS", ()):
        cases.append(
            Case(
                f"delta_{m}",
                _delta(m),
                "delta",
                f"imu_dcm.integrate_delta(method={m!r}) on exact delta angles",
                "see convergence",
                input="delta",
                stride=_DELTA_STRIDE.get(m, 1),
            )
        )
    cases += [
        Case(name, p.fn, "peer", p.description, {"first": "1"}.get(p.order, p.order))
        for name, p in PEERS.items()
    ]
    return cases


def _streaming_methods() -> tuple[str, ...]:
    names = getattr(_integrator_class(), "METHODS", None) or imu_dcm.METHODS
    return tuple(m for m in names if m != "rotvec_sum")


# ----------------------------------------------------------------------------------------------
# Measurement
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Measurement:
    """One method on one scene at one rate.

    Attributes
    ----------
    scene, rate_hz, case : scene key, sample rate (Hz), method name.
    n_samples : samples integrated.
    max_err_deg : max total attitude error against the truth over all samples, deg.
    ns_per_sample : median wall time per sample over the timed rounds, ns (NaN if untimed).
    ratio_vs_reference : reference ns/sample divided by this one (> 1: faster).
    """

    scene: str
    rate_hz: float
    case: str
    n_samples: int
    max_err_deg: float
    ns_per_sample: float
    ratio_vs_reference: float


def _truth(traj, rate_hz: float, duration_s: float) -> tuple[NDArray, NDArray, NDArray]:
    n = round(duration_s * rate_hz) + 1
    t = np.arange(n) / rate_hz
    q, w = traj.at(t)
    return t, np.asarray(q, dtype=float), np.ascontiguousarray(w, dtype=float)


def _max_err(q_est: NDArray, q_true: NDArray, stride: int = 1) -> float:
    """Max total error (deg) over the stamps the method reported (NaN rows: streaming magnus4
    skips warm-up stamps, delta-angle sets report every ``stride``-th stamp); 180 if it
    reported fewer than all but 3 of the stamps it should."""
    q_est = np.asarray(q_est, dtype=float)
    ok = np.all(np.isfinite(q_est), axis=1)
    if np.count_nonzero(ok) < (len(q_est) - 1) // stride + 1 - 3:
        return 180.0
    return float(np.max(attitude_error_deg(q_est[ok], q_true[ok]).total_deg))


#: Clocks for :func:`measure`: wall time, or the CPU time of this process (which leaves out the
#: time other processes hold the CPU on a shared machine; equal to wall time for these
#: single-threaded cases on an idle one).
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}
CLOCK_TEXT = {"wall": "wall time", "cpu": "CPU time"}


def measure(
    scenes: Sequence[Scene],
    rates_hz: Sequence[float],
    cases: Sequence[Case],
    rounds: int,
    progress: Callable[[str], None] = print,
    clock: str = "wall",
) -> list[Measurement]:
    """Time every case on every scene and rate (interleaved rounds, warm-up), and score it.

    ``clock`` is a key of :data:`CLOCKS`.
    """
    out: list[Measurement] = []
    for sc in scenes:
        progress(f"pareto: truth for {sc.title}")
        traj = sc.make()
        for rate in rates_hz:
            t, q_true, w = _truth(traj, rate, sc.duration_s)
            q0 = q_true[0]
            progress(
                f"pareto: {sc.title} at {rate:g} Hz ({len(t)} samples, {len(cases)} methods,"
                f" {rounds} rounds)"
            )
            feed = {"rate": w}
            if any(c.input == "delta" for c in cases):
                feed["delta"] = np.ascontiguousarray(traj.delta_angles(t), dtype=float)
            errs = {c.name: _max_err(c.fn(feed[c.input], t, q0), q_true, c.stride) for c in cases}
            timings = interleaved_medians(
                {
                    c.name: ((lambda f=c.fn, x=feed[c.input], t=t, q0=q0: f(x, t, q0)), len(t))
                    for c in cases
                },
                rounds=rounds,
                warmup=1,
                clock=CLOCKS[clock],
            )
            ref = timings[REFERENCE].ns_per_item if REFERENCE in timings else float("nan")
            for c in cases:
                ns = timings[c.name].ns_per_item
                out.append(Measurement(sc.key, rate, c.name, len(t), errs[c.name], ns, ref / ns))
    return out


def convergence(
    scenes: Sequence[Scene],
    rates_hz: Sequence[float] = CONVERGENCE_RATES_HZ,
    methods: Sequence[str] = ("start", "end", "trapezoid", "coning", "magnus4"),
    progress: Callable[[str], None] = print,
) -> dict[str, dict[str, NDArray]]:
    """Max error (deg) of each batch method against dt, per scene (untimed).

    Keys of each scene's dict: ``dt_s``, the rate methods, and ``delta_<m>`` for every
    delta-angle method of ``imu_dcm.integrate_delta`` (fed exact delta angles).
    """
    delta = tuple(getattr(imu_dcm, "DELTA_METHODS", ()))
    res: dict[str, dict[str, NDArray]] = {}
    for sc in scenes:
        progress(f"convergence: {sc.title}, {len(rates_hz)} rates")
        traj = sc.make()
        keys = list(methods) + [f"delta_{m}" for m in delta]
        errs = {m: np.empty(len(rates_hz)) for m in keys}
        for k, rate in enumerate(rates_hz):
            t, q_true, w = _truth(traj, rate, sc.duration_s)
            for m in methods:
                errs[m][k] = _max_err(imu_dcm.integrate(w, t, q_true[0], m).as_quat(), q_true)
            if delta:
                dth = np.ascontiguousarray(traj.delta_angles(t), dtype=float)
                for m in delta:
                    errs[f"delta_{m}"][k] = _max_err(
                        _delta(m)(dth, t, q_true[0]), q_true, _DELTA_STRIDE.get(m, 1)
                    )
        res[sc.key] = {"dt_s": 1.0 / np.asarray(rates_hz, dtype=float), **errs}
    return res


def observed_orders(
    conv: dict[str, dict[str, NDArray]], lo_deg: float = 1e-7, hi_deg: float = 1.0
) -> dict[str, dict[str, float]]:
    """Least-squares slope of log error against log dt per scene and method, over the points
    with ``lo_deg < error < hi_deg`` (above the truth's accuracy floor, in the asymptotic range);
    NaN with fewer than 3 such points."""
    out: dict[str, dict[str, float]] = {}
    for key, res in conv.items():
        dt = res["dt_s"]
        out[key] = {}
        for m, e in res.items():
            if m == "dt_s":
                continue
            ok = (e > lo_deg) & (e < hi_deg)
            out[key][m] = (
                float(np.polyfit(np.log(dt[ok]), np.log(e[ok]), 1)[0])
                if np.count_nonzero(ok) >= 3
                else float("nan")
            )
    return out


def convergence_markdown(conv: dict[str, dict[str, NDArray]]) -> list[str]:
    """Markdown table of observed orders (scene x method)."""
    orders = observed_orders(conv)
    titles = {s.key: s.title for s in SCENES}
    methods = [m for m in next(iter(conv.values())) if m != "dt_s"]
    md = [
        "## Convergence (chart `convergence.png`)",
        "",
        "Observed order: least-squares slope of log(max error) against log(dt) over the rates "
        "whose error lies between 1e-7° (above the truth's accuracy) and 1° (asymptotic range); "
        "— where fewer than 3 rates qualify. Rates: "
        + ", ".join(f"{1 / d:g}" for d in next(iter(conv.values()))["dt_s"])
        + " Hz.",
        "",
        "| scene | " + " | ".join(f"`{m}`" for m in methods) + " |",
        "|---" * (len(methods) + 1) + "|",
    ]
    for key, row in orders.items():
        md.append(
            f"| {titles.get(key, key)} | "
            + " | ".join("—" if not np.isfinite(row[m]) else f"{row[m]:.2f}" for m in methods)
            + " |"
        )
    md.append("")
    return md


# ----------------------------------------------------------------------------------------------
# Charts
# ----------------------------------------------------------------------------------------------

_STYLE = {
    # imu_dcm batch: filled markers, solid lines, cool colours
    "batch_start": ("#9ecae1", "v", "-"),
    "batch_end": ("#6baed6", "^", "-"),
    "batch_trapezoid": ("#2171b5", "s", "-"),
    "batch_coning": ("#08519c", "D", "-"),
    "batch_magnus4": ("#08306b", "o", "-"),
    "batch_rotvec_sum": ("#41ab5d", "*", "-"),
    # peers: warm colours, dashed
    "reference_loop": ("#d62728", "X", "--"),
    "scipy_loop": ("#ff7f0e", "P", "--"),
    "ahrs_angular_rate": ("#8c564b", "h", "--"),
    "imufusion_gain0": ("#e377c2", "<", "--"),
    "vqf_batch": ("#bcbd22", ">", "--"),
    "vqf_update_gyr": ("#7f7f7f", "d", "--"),
    # imu_dcm on delta angles: purples, solid, half-filled look via small markers
    "delta_plain": ("#9e9ac8", "$1$", "-"),
    "delta_one_plus_previous": ("#807dba", "p", "-"),
    "delta_two_sample": ("#6a51a3", "$2$", "-"),
    "delta_three_sample": ("#3f007d", "$3$", "-"),
}
_STREAM_COLOURS = {
    "start": "#c7e9c0",
    "end": "#a1d99b",
    "trapezoid": "#74c476",
    "coning": "#31a354",
    "magnus4": "#006d2c",
}


def _style(name: str) -> tuple[str, str, str, str]:
    """(colour, marker, linestyle, marker face) of a case."""
    if name in _STYLE:
        c, m, ls = _STYLE[name]
        return c, m, ls, c
    for prefix, ls in (("stream_many_", "-."), ("stream_", ":")):
        if name.startswith(prefix):
            method = name[len(prefix) :]
            c = _STREAM_COLOURS.get(method, "#2ca02c")
            return c, _STYLE.get(f"batch_{method}", (c, "o", "-"))[1], ls, "none"
    return "#333333", "o", "-", "#333333"


def _label(name: str, cases: dict[str, Case]) -> str:
    c = cases.get(name)
    if c is None:
        return name
    if c.family == "peer":
        return f"{name} (peer, order {c.order})"
    if c.family == "delta":
        return f"{name} (Δθ input)"
    return f"{name} (order {c.order})"


#: Cases left off the main chart to keep it readable: streaming start/end/coning (cost as the
#: streaming trapezoid, errors as their batch twins) and two of the four delta-angle rules;
#: ``pareto_all.png`` and ``results.md`` have them.
MAIN_CHART_SKIP = tuple(
    f"{p}{m}" for p in ("stream_", "stream_many_") for m in ("start", "end", "coning")
) + ("delta_plain", "delta_three_sample")


def _grid(figsize: tuple[float, float]):
    """A 2x2 figure on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(2, 2, figsize=figsize)


def _finish_grid(fig, axes, used: int, path, suptitle: str, rect: tuple, **legend) -> None:
    """Hide the unused panels, one legend (``legend``: its keywords) from the first panel's
    lines, the figure's title; save, close."""
    import matplotlib.pyplot as plt

    for ax in axes.flat[used:]:
        ax.set_visible(False)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, **legend)
    fig.suptitle(suptitle, fontsize=14)
    fig.tight_layout(rect=rect)
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def plot_pareto(
    meas: Sequence[Measurement],
    cases: Sequence[Case],
    path: str | Path,
    title_note: str = "",
    skip: Sequence[str] = (),
    label_rates: str = "batch_magnus4",
    clock: str = "wall",
) -> None:
    """Write the 2x2 log-log Pareto chart: ns/sample against max error, a line per method.

    ``skip`` names cases left off; the points of ``label_rates`` are labelled with their rate.
    """
    by_case = {c.name: c for c in cases}
    scenes = list(dict.fromkeys(m.scene for m in meas))
    titles = {s.key: s.title for s in SCENES}
    fig, axes = _grid((17, 10.5))
    for ax, key in zip(axes.flat, scenes, strict=False):
        for c in cases:
            if c.name in skip:
                continue
            pts = sorted(
                (m for m in meas if m.scene == key and m.case == c.name), key=lambda m: m.rate_hz
            )
            if not pts:
                continue
            colour, marker, ls, face = _style(c.name)
            x = [m.ns_per_sample for m in pts]
            y = [max(m.max_err_deg, 1e-12) for m in pts]
            ax.loglog(
                x,
                y,
                ls,
                color=colour,
                marker=marker,
                mfc=face,
                ms=7,
                lw=1.4,
                label=_label(c.name, by_case),
            )
            if c.name == label_rates:
                _label_rates(ax, pts, colour)
        rates = sorted({m.rate_hz for m in meas if m.scene == key})
        ax.set_title(f"{titles.get(key, key)}  (points: {rates[0]:g}–{rates[-1]:g} Hz)")
        ax.set_xlabel(f"{CLOCK_TEXT[clock]} per gyro sample, ns (median, 1 thread)")
        ax.set_ylabel("max attitude error vs truth, deg")
        ax.grid(True, which="major", alpha=0.3)
    _finish_grid(
        fig,
        axes,
        len(scenes),
        path,
        "Speed against accuracy: lower-left is better" + title_note,
        (0, 0, 0.73, 0.97),
        loc="center right",
        fontsize=9,
        frameon=True,
        title="method (higher rate → lower error)",
    )


def _label_rates(ax, pts: Sequence[Measurement], colour: str) -> None:
    """Label each point with its rate, skipping a label that would sit on the previous one
    (errors at a floor)."""
    last_y = None
    for m in pts:
        if last_y is not None and max(m.max_err_deg, 1e-12) > last_y / 3.0:
            continue
        last_y = max(m.max_err_deg, 1e-12)
        ax.annotate(
            f"{m.rate_hz:g} Hz",
            (m.ns_per_sample, max(m.max_err_deg, 1e-12)),
            textcoords="offset points",
            xytext=(8, 0),
            ha="left",
            va="center",
            fontsize=8,
            color=colour,
        )


def plot_convergence(conv: dict[str, dict[str, NDArray]], path: str | Path) -> None:
    """Write the convergence chart: max error against dt per method, with slope 1, 2, 4 guides."""
    titles = {s.key: s.title for s in SCENES}
    fig, axes = _grid((14, 10))
    for ax, (key, res) in zip(axes.flat, conv.items(), strict=False):
        dt = res["dt_s"]
        for m, e in res.items():
            if m == "dt_s":
                continue
            if m.startswith("delta_"):
                colour, marker, _ls, _f = _style(m)
                label = f"{m} (Δθ input)"
            else:
                colour, marker, _ls, _f = _style(f"batch_{m}")
                label = f"{m} (order {_ORDER[m]})"
            ax.loglog(dt, np.maximum(e, 1e-13), "-", color=colour, marker=marker, ms=6, label=label)
        # Theoretical slopes C dt^p, drawn 3x above the method of that order and anchored at its
        # coarsest step with an error below 1° (the asymptotic range), labelled at the finest dt.
        for p, m in ((1, "end"), (2, "trapezoid"), (4, "magnus4")):
            if m not in res:
                continue
            ok = np.flatnonzero(res[m] < 1.0)
            if not len(ok):
                continue
            i = ok[np.argmax(dt[ok])]
            guide = 3.0 * res[m][i] * (dt / dt[i]) ** p
            ax.loglog(dt, guide, "k", ls=(0, (4, 3)), lw=0.9, alpha=0.7)
            ax.annotate(
                f"slope {p}", (dt.min(), guide[np.argmin(dt)]), fontsize=9, ha="left", va="bottom"
            )
        lo = min(float(np.min(e)) for m, e in res.items() if m != "dt_s")
        ax.set_title(titles.get(key, key))
        ax.set_xlabel("dt = 1 / sample rate, s")
        ax.set_ylabel("max attitude error vs truth, deg")
        ax.set_ylim(bottom=max(lo / 5.0, 1e-13))
        ax.grid(True, which="major", alpha=0.3)
    _finish_grid(
        fig,
        axes,
        len(conv),
        path,
        "Convergence: max error against step, with theoretical slopes (dashed)",
        (0, 0.08, 1, 0.97),
        loc="lower center",
        ncol=5,
        fontsize=9,
        title="imu_dcm method (rate input: integrate; Δθ input: integrate_delta)",
    )


# ----------------------------------------------------------------------------------------------
# Table
# ----------------------------------------------------------------------------------------------


def peer_versions() -> dict[str, str]:
    """Installed versions of numpy, scipy and the peer libraries."""
    out = {}
    for pkg in ("numpy", "scipy", "ahrs", "imufusion", "vqf", "matplotlib", "threadpoolctl"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _g(x: float, digits: int = 2) -> str:
    if not np.isfinite(x):
        return "—"
    if x == 0:
        return "0"
    if abs(x) >= 100 or abs(x) < 1e-2:
        return f"{x:.{digits}g}" if abs(x) < 1e5 and abs(x) >= 1e-2 else f"{x:.{digits}e}"
    return f"{x:.{digits + 1}g}"


def results_markdown(
    meas: Sequence[Measurement],
    cases: Sequence[Case],
    rounds: int,
    command: str,
    clock: str = "wall",
) -> list[str]:
    """Markdown: versions, method list, then per scene a table (methods x rates)."""
    vers = peer_versions()
    titles = {s.key: s.title for s in SCENES}
    md = [
        "## Speed against accuracy",
        "",
        (
            f"Command: `{command}`. Machine: {platform.machine()}, "
            f"{platform.python_implementation()} {platform.python_version()}, one BLAS thread; "
            f"{CLOCK_TEXT[clock]} per sample, medians "
            f"of {rounds} interleaved rounds "
            "after one warm-up; every method integrates the same exact rate samples from the true "
            "initial attitude. Error = max total attitude error against the truth over all "
            "samples; "
            f"ratio = `{REFERENCE}` ns/sample ÷ the method's (same run; > 1 is faster). No peer is "
            "timed on a prefix: every method runs every sample."
        ),
        "",
        "Versions: " + ", ".join(f"{k} {v}" for k, v in vers.items()) + f", imu_dcm "
        f"{imu_dcm.__version__}.",
        "",
        "| method | family | order | what it is |",
        "|---|---|---|---|",
    ]
    md += [f"| `{c.name}` | {c.family} | {c.order} | {c.description} |" for c in cases]
    md.append("")
    for key in dict.fromkeys(m.scene for m in meas):
        rates = sorted({m.rate_hz for m in meas if m.scene == key})
        md += [
            f"### {titles.get(key, key)}",
            "",
            "Cells: max error (deg) · ns/sample · speed ratio vs reference.",
            "",
            "| method | " + " | ".join(f"{r:g} Hz" for r in rates) + " |",
            "|---" * (len(rates) + 1) + "|",
        ]
        for c in cases:
            cells = []
            for r in rates:
                m = next(
                    (m for m in meas if m.scene == key and m.case == c.name and m.rate_hz == r),
                    None,
                )
                cells.append(
                    "—"
                    if m is None
                    else f"{_g(m.max_err_deg)}° · {m.ns_per_sample:,.0f} · "
                    f"{_g(m.ratio_vs_reference)}×"
                )
            md.append(f"| `{c.name}` | " + " | ".join(cells) + " |")
        md.append("")
    return md


def summary_rows(meas: Sequence[Measurement], scene: str, rate_hz: float) -> list[Measurement]:
    """Measurements of one scene and rate, sorted by cost."""
    return sorted(
        (m for m in meas if m.scene == scene and m.rate_hz == rate_hz),
        key=lambda m: m.ns_per_sample,
    )


#: Errors at or above this (deg) are not estimates; such cases are left off the front.
FRONT_MAX_ERR_DEG = 90.0


def pareto_front(rows: Sequence[Measurement]) -> list[str]:
    """Names of the cases not dominated (no other is both cheaper and at most as wrong).

    Cases with an error of ``FRONT_MAX_ERR_DEG`` or more are excluded (a 180° estimate is cheap
    but is no estimate).
    """
    rows = [r for r in rows if r.max_err_deg < FRONT_MAX_ERR_DEG]
    front = []
    for a in rows:
        # Errors equal to 1e-6 relative count as equal (batch and streaming twins agree to
        # rounding, ~1e-15), so the cheaper twin dominates.
        dominated = any(
            b is not a
            and b.ns_per_sample <= a.ns_per_sample
            and b.max_err_deg <= a.max_err_deg * (1.0 + 1e-6)
            and (b.ns_per_sample < a.ns_per_sample or b.max_err_deg < a.max_err_deg * (1.0 - 1e-6))
            for b in rows
        )
        if not dominated:
            front.append(a.case)
    return front


def summary_markdown(
    meas: Sequence[Measurement],
    scene: str = "heavy_top_1.2s",
    rates_hz: Sequence[float] = (2000.0, 200.0),
) -> list[str]:
    """Headline tables: one scene at the measured rates nearest ``rates_hz``, sorted by cost."""
    have = sorted({m.rate_hz for m in meas if m.scene == scene})
    if not have:
        return []
    titles = {s.key: s.title for s in SCENES}
    md = []
    for want in dict.fromkeys(min(have, key=lambda r: abs(np.log(r / w))) for w in rates_hz):
        rows = summary_rows(meas, scene, want)
        front = pareto_front(rows)
        md += [
            f"## Headline: {titles.get(scene, scene)} at {want:g} Hz",
            "",
            (
                f"On the front: no other method is both cheaper and more accurate (errors ≥ "
                f"{FRONT_MAX_ERR_DEG:g}° excluded)."
            ),
            "",
            "| method | max error, deg | ns/sample | speed ratio vs reference | on the front |",
            "|---|---|---|---|---|",
        ]
        md += [
            f"| `{m.case}` | {_g(m.max_err_deg)} | {m.ns_per_sample:,.0f} | "
            f"{_g(m.ratio_vs_reference)}× | {'yes' if m.case in front else ''} |"
            for m in rows
        ]
        md.append("")
    return md
