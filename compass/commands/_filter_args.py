"""The filter's command-line options shared by ``compass live`` and ``compass attitude --filter``."""

from __future__ import annotations

MAG_LATENCY_HELP = ("compensate the magnetometer's latency against the gyro that the calibration's gyro-aided tumble "
                    "fit found (tumble.gyro.mag_latency_s, when late beyond 3 sigma): each field reading is turned "
                    "forward by the gyro over it; off by default (on BROAD it cost the undisturbed trials' heading: "
                    "docs/benchmarks.md)")


def add_mag_latency_argument(p, *, with_filter: bool = False) -> None:
    """``--mag-latency`` (``FilterConfig.from_model(model, mag_latency=True)``)."""
    p.add_argument("--mag-latency", action="store_true",
                   help=("with --filter: " if with_filter else "") + MAG_LATENCY_HELP)


def filter_config(model, args):
    """``compass live``'s :class:`~compass.filter.FilterConfig`: the calibration's, with ``--mag-latency`` and
    ``--gravity`` (``compass attitude --filter`` passes both to :func:`compass.replay.replay_file`, which does the same)."""
    from dataclasses import replace

    from ..filter import FilterConfig

    config = FilterConfig.from_model(model, mag_latency=args.mag_latency)
    return config if args.gravity is None else replace(config, gravity=args.gravity)
