"""The fuzz campaign's live class: a bad message on each live source (stdin lines, UDP
datagrams, a Foxglove WebSocket server, MAVLink over UDP), among known good samples.

Each case is one run of ``python -m imu_dcm.live SOURCE --idle-stop 0.4 --summary-json F``
(bounded by ``fuzzlive.RUN_TIMEOUT_S``), with 1 to 4 bad messages of one damage class (garbage
bytes, truncated messages, huge numbers, NaN/Inf, wrong JSON types, deep nesting, out-of-range
stamps, oversize lines; for WebSocket and MAVLink their own frames) drawn from
``numpy.random.default_rng(SEED)``. For every case (:func:`fuzzlive.violations`):

* no traceback and no Python exception name in stdout or stderr; no hang;
* exit 0 (good samples were sent, as docs/live.md says) or 1/2, never another code;
* a ``--summary-json`` without NaN or Infinity, and the final attitude the exact spin;
* each bad message counted (malformed + NaN/Inf + implausible), and every good sample
  integrated: exactly on the lossless transports (stdin, WebSocket); on UDP the datagrams the
  system dropped (``lost_by_system``) close the account exactly.

The case lists are printed per class when one fails.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import fuzzlive
import numpy as np
import pytest

pytestmark = pytest.mark.slow

SEED = 20261202
N_GOOD = 201  # 1 s at 200 Hz


def _report(results: list[tuple[str, list[str]]]) -> None:
    bad = [f"{name}: {'; '.join(v)}" for name, v in results if v]
    assert not bad, f"{len(bad)} of {len(results)} cases failed:\n" + "\n".join(bad)


def _in_pairs(fn, cases):
    with ThreadPoolExecutor(2) as ex:  # two cores in CI: two runs at a time
        return list(ex.map(fn, cases))


def test_bad_lines_on_stdin(tmp_path):
    cases = fuzzlive.line_cases(np.random.default_rng([SEED, 1]), 2, N_GOOD, udp=False)

    def one(c):
        summary = tmp_path / f"{c.name}.json"
        proc = fuzzlive.start(fuzzlive.live_argv("-", summary), stdin=True)
        run = fuzzlive.finish(proc, summary, b"\n".join(c.lines()) + b"\n")
        v = fuzzlive.violations(run, expect_samples=True)
        if run.summary is not None and not v:
            s = run.summary
            if s["samples"] != c.n_good:
                v.append(f"{s['samples']} samples integrated of {c.n_good} good")
            if fuzzlive.bad_counted(s) != len(c.bad):
                v.append(f"{fuzzlive.bad_counted(s)} counted of {len(c.bad)} bad lines")
        return c.name, v

    _report(_in_pairs(one, cases))


def test_bad_datagrams_on_udp(tmp_path):
    cases = fuzzlive.line_cases(np.random.default_rng([SEED, 2]), 1, N_GOOD, udp=True)

    def one(c):
        summary = tmp_path / f"{c.name}.json"
        port = fuzzlive.free_udp_port()
        proc = fuzzlive.start(fuzzlive.live_argv(f"udp://127.0.0.1:{port}", summary))
        if fuzzlive.wait_bound(port, proc):
            fuzzlive.send_datagrams(port, c.lines())
        run = fuzzlive.finish(proc, summary)
        v = fuzzlive.violations(run, expect_samples=True)
        if run.summary is not None and not v:
            s = run.summary
            lost = s["lost_by_system"]
            # one line a datagram: every datagram is integrated, counted bad or lost
            if s["samples"] + fuzzlive.bad_counted(s) + lost != c.n_good + len(c.bad):
                v.append(
                    f"{s['samples']} samples + {fuzzlive.bad_counted(s)} counted + {lost} "
                    f"lost != {c.n_good} good + {len(c.bad)} bad"
                )
            if s["samples"] > c.n_good:
                v.append(f"{s['samples']} samples integrated of {c.n_good} good")
        return c.name, v

    _report(_in_pairs(one, cases))
