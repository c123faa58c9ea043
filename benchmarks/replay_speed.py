"""Replay speed against a plain per-message decode loop over the same bag (issue 4's target).

``python -m benchmarks.replay_speed [--bag DIR] [--rounds N]``

Cases, timed in interleaved rounds after a warm-up, one BLAS thread (see
:mod:`benchmarks.timing`):

* ``decode loop``: ``mcap.reader.make_reader`` with the ``mcap_ros2`` decoder factory,
  ``iter_decoded_messages()`` over every message of the bag (one Python object per message);
* ``read_log``: :func:`imu_dcm.bag_reader.read_log` (bulk numpy decoding of the IMU and truth);
* ``replay``: :func:`imu_dcm.replay.replay` without the viewer: reading, cleaning, bias from
  rest, magnus4 integration, truth slerp and the error.

Rates are the bag's message count divided by the median time, so the ratio of ``replay`` to
``decode loop`` is the speed-up for the same bag. Target: >= 10x.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from benchmarks.timing import limit_threads_env

REPO = Path(__file__).resolve().parents[1]
DEFAULT_BAG = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"
TARGET_RATIO = 10.0


def decode_loop(mcap_path: Path) -> int:
    """The reference: decode every message with the mcap_ros2 decoder; returns the count."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    n = 0
    with open(mcap_path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, _channel, _message, _decoded in reader.iter_decoded_messages():
            n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.replay_speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bag", type=Path, default=DEFAULT_BAG, help="bag folder or .mcap")
    p.add_argument("--rounds", type=int, default=3, help="timed rounds (default 3)")
    args = p.parse_args(argv)

    limit_threads_env()
    import warnings

    from benchmarks.timing import interleaved_medians, single_thread
    from imu_dcm.bag_reader import read_log, resolve_mcap_path
    from imu_dcm.replay import replay

    mcap_path = resolve_mcap_path(args.bag)
    n_msgs = decode_loop(mcap_path)

    def run_replay():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return replay(args.bag)

    cases = {
        "decode loop (mcap + mcap_ros2)": (lambda: decode_loop(mcap_path), n_msgs),
        "read_log (bulk numpy)": (lambda: read_log(args.bag), n_msgs),
        "replay, no viewer": (run_replay, n_msgs),
    }
    with single_thread():
        res = interleaved_medians(cases, rounds=args.rounds, warmup=1)
    base = res["decode loop (mcap + mcap_ros2)"]
    shown = args.bag.resolve()
    shown = shown.relative_to(REPO) if shown.is_relative_to(REPO) else args.bag
    print(f"bag: {shown} ({n_msgs} messages, {mcap_path.stat().st_size / 1e6:.1f} MB); "
          f"median of {args.rounds} interleaved rounds, 1 thread")  # fmt: skip
    print(f"{'case':<32} {'median s':>9} {'msgs/s':>12} {'vs loop':>8}")
    for name, t in res.items():
        print(f"{name:<32} {t.median_s:>9.3f} {t.items_per_s:>12,.0f} "
              f"{base.median_s / t.median_s:>7.1f}x")  # fmt: skip
    ratio = base.median_s / res["replay, no viewer"].median_s
    verdict = "meets" if ratio >= TARGET_RATIO else "MISSES"
    print(f"replay is {ratio:.1f}x the decode loop's message rate ({verdict} the "
          f">= {TARGET_RATIO:.0f}x target)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
