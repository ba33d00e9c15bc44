"""``qz impedance-sweep`` and ``qz classify {collect,train,experiment}`` (paper 002).

``qz impedance-sweep [--json] [--out DIR]`` runs Fig. 13's one-leg model at 5, 15 and 25 kN/m
and prints ``{"stiffness_N_per_m": [...], "max_error_m": [...], "oscillates": [...]}``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from qz_drake.errors import bad_value


def _positive_list(text: str, field: str) -> list[float]:
    try:
        values = [float(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise bad_value(field, text, "expected comma-separated numbers") from None
    if not values or not all(math.isfinite(v) and v > 0 for v in values):
        raise bad_value(field, text, "expected positive numbers")
    return values


def run_impedance_sweep(args) -> int:
    from qz_drake.classification.impedance_sweep import ImpedanceSweepConfig, plot_sweep, run_sweep

    config = ImpedanceSweepConfig()
    if args.stiffness is not None:
        config.stiffnesses = _positive_list(args.stiffness, "--stiffness")
    if args.torque_lag is not None:
        if not (math.isfinite(args.torque_lag) and args.torque_lag >= 0):
            raise bad_value("--torque-lag", args.torque_lag, "must be a non-negative number of seconds")
        config.torque_lag = args.torque_lag
    result = run_sweep(config)
    summary = {k: result[k] for k in ("stiffness_N_per_m", "max_error_m", "oscillates")}
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        summary_file = dict(summary, oscillation_amplitude_m=result["oscillation_amplitude_m"],
                            config=result["config"], png=plot_sweep(result, out / "impedance_sweep.png"))
        (out / "impedance_sweep.json").write_text(json.dumps(summary_file, indent=2))
    if args.json:
        print(json.dumps(summary))
    else:
        for k, e, o in zip(summary["stiffness_N_per_m"], summary["max_error_m"], summary["oscillates"]):
            print(f"K = {k / 1e3:5.1f} kN/m   max error {e:.4f} m   {'oscillates' if o else ''}")
    return 0


def register(subparsers) -> None:
    """Adds ``impedance-sweep`` and ``classify`` to the ``qz`` command."""
    p = subparsers.add_parser("impedance-sweep", help="leg impedance stiffness sweep (paper 002 Fig. 13)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--out", default=None, help="folder for impedance_sweep.png and .json")
    p.add_argument("--stiffness", default=None, metavar="K1,K2,...", help="leg stiffnesses [N/m]")
    p.add_argument("--torque-lag", type=float, default=None, help="torque-loop lag [s] (default 0.012)")
    p.set_defaults(func=run_impedance_sweep)
