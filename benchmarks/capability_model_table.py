"""A trained model's test-scene metrics as the Markdown table of BENCHMARKS.md "capability-networks".

    python benchmarks/capability_model_table.py [qz_drake/data/capability_model]

Reads what `qz capability train` wrote: ``report.json`` (the success output and the baselines,
one row per network) and each network's card (the plan output's test metrics). Prints the table,
then the means over the networks and the counts against the aims (AUC >= 0.9 on the move
networks, ECE < 0.05, ECE within 0.02 of its floor, both baselines beaten).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from qz_drake.capability.model import DEFAULT_MODEL_DIR

HEADER = ("| network | test n (successes) | CNN AUC | CNN Brier | CNN ECE (floor) | plan output AUC / Brier "
          "| logistic AUC / Brier | boosting AUC | base-rate Brier | loss | beats both |")


def table(model_dir: Path) -> str:
    report = json.loads((model_dir / "report.json").read_text())
    rows = report["networks"]
    lines = [HEADER, "|" + " --- |" * HEADER.count(" | ") + " --- |"]
    plans = []
    for r in rows:
        card = json.loads((model_dir / f"{r['topology']}_{r['kind']}.json").read_text())
        plan = card["test"]["plan"]
        plans.append(plan)
        lines.append(
            f"| {r['topology']}/{r['kind']} | {r['n']} ({r['positives']}) | {r['auc']:.3f} | {r['brier']:.3f} "
            f"| {r['ece']:.3f} ({r['ece_floor']:.3f}) | {plan['auc']:.2f} / {plan['brier']:.3f} "
            f"| {r['logistic_auc']:.2f} / {r['logistic_brier']:.3f} | {r['boosting_auc']:.2f} "
            f"| {r['base_rate_brier']:.3f} | {r['loss']} | {'yes' if r['beats_baselines'] else 'no'} |")

    def mean(values) -> float:
        values = list(values)
        return sum(values) / len(values)

    by_kind = ", ".join(f"{kind} {mean(r['auc'] for r in rows if r['kind'] == kind):.3f}"
                        for kind in ("orthogonal", "diagonal", "turn") if any(r["kind"] == kind for r in rows))
    moves = [r for r in rows if r["kind"] != "turn"]
    lines += ["", f"Mean over the {len(rows)}: success AUC {mean(r['auc'] for r in rows):.3f} ({by_kind}), "
              f"Brier {mean(r['brier'] for r in rows):.3f}, ECE {mean(r['ece'] for r in rows):.3f} against a floor of "
              f"{mean(r['ece_floor'] for r in rows):.3f}; logistic regression {mean(r['logistic_auc'] for r in rows):.3f} / "
              f"{mean(r['logistic_brier'] for r in rows):.3f}; gradient boosting {mean(r['boosting_auc'] for r in rows):.3f} / "
              f"{mean(r['boosting_brier'] for r in rows):.3f}; base-rate Brier {mean(r['base_rate_brier'] for r in rows):.3f}. "
              f"Plan output: AUC {mean(p['auc'] for p in plans):.3f}, Brier {mean(p['brier'] for p in plans):.3f}. "
              f"Both baselines beaten: {sum(r['beats_baselines'] for r in rows)} of {len(rows)}; AUC >= 0.9: "
              f"{sum(r['auc'] >= 0.9 for r in moves)} of {len(moves)} move networks; ECE < 0.05: "
              f"{sum(r['ece'] < 0.05 for r in rows)}; ECE within 0.02 of its floor: "
              f"{sum(r['ece'] <= r['ece_floor'] + 0.02 for r in rows)}."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", nargs="?", default=str(DEFAULT_MODEL_DIR), help="model folder (default: shipped)")
    print(table(Path(parser.parse_args().model)))


if __name__ == "__main__":
    main()
