"""The adaptive-locomotion experiments of paper 002, section 5, in simulation.

* Figs. 15-16: Qingzhui steps in place (0 m/s) on foam and trots at 0.6 m/s on foam and on
  concrete, once with every leg at the fixed default stiffness (9 kN/m) and once with the
  TerrainClassifier switching each leg's stiffness (the paper's presets: 7 kN/m on concrete,
  11 kN/m on foam). The spread of the body's vertical acceleration (IMU, the paper's
  "acceleration along y", the direction of gravity) and of its height is compared over the
  same late window, after the classifier has confirmed the terrain.
* The paper chose its presets by experiment on its robot. The same choice is made here on
  the simulated robot: a sweep trots each material at 0.6 m/s with each of the paper's three
  stiffnesses fixed and takes, per material, the one with the narrowest acceleration box;
  a third run per case switches to those "simulation presets".
* The mixed floor: Qingzhui trots across stripes of concrete, wood and foam; each leg's
  confirmed label over time is compared with the material under the foot, and stance by
  stance: settled accuracy (errors) apart from the switching latency (the confirmation rule).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from qz_drake.progress import ProgressReport
from qz_drake.robot.params import LEG_NAMES, NUM_LEGS
from qz_drake.state_layout import BASE_POS, BASE_Z
from qz_drake.classification.terrain_classifier import CONFIRMATIONS


@dataclasses.dataclass
class ExperimentConfig:
    # (material, forward speed [m/s]) of the vibration cases: Fig. 15 steps on foam at 0,
    # Fig. 16 trots at 0.6 m/s on concrete and on foam.
    vibration_cases: list[tuple[str, float]] = dataclasses.field(
        default_factory=lambda: [("foam", 0.0), ("foam", 0.6), ("concrete", 0.6)])
    # Simulated time of each vibration run, and the start of the judged window (the adaptive
    # legs have switched by then: three stances plus the speed ramp). [s]
    vibration_duration: float = 10.0
    judge_from: float = 4.0
    # Mixed floor: speed [m/s], stripe depth [m] and simulated time [s].
    mixed_speed: float = 0.4
    mixed_patch_length: float = 2.0
    mixed_duration: float = 24.0
    # Payload during the experiments. [kg]
    payload_kg: float = 5.0
    # Stiffnesses the preset sweep tries per material (the paper's three) [N/m]; the sweep's
    # runs last sweep_duration and are judged from sweep_judge_from [s]. Empty: no sweep.
    preset_candidates: list[float] = dataclasses.field(default_factory=lambda: [7000.0, 9000.0, 11000.0])
    sweep_duration: float = 6.0
    sweep_judge_from: float = 3.0

    @classmethod
    def quick(cls) -> "ExperimentConfig":
        """Short runs for tests and notebooks: one vibration case, a short mixed floor."""
        return cls(vibration_cases=[("foam", 0.0)], vibration_duration=3.5, judge_from=2.5, mixed_speed=0.6,
                   mixed_patch_length=1.0, mixed_duration=3.0, preset_candidates=[])


def spread(values: np.ndarray) -> dict:
    """Box-plot numbers of a signal: interquartile range, 5-95 % range, standard deviation."""
    q5, q25, q50, q75, q95 = np.percentile(values, [5, 25, 50, 75, 95])
    return {"iqr": float(q75 - q25), "p5_p95": float(q95 - q5), "std": float(np.std(values)),
            "median": float(q50), "min": float(np.min(values)), "max": float(np.max(values))}


def preset_sweep(materials, config: ExperimentConfig, speed: float = 0.6) -> dict:
    """Per material, the acceleration spread of a 0.6 m/s trot at each candidate stiffness, and
    the candidate with the narrowest box (the "simulation preset")."""
    from qz_drake.classification.runs import simulate_trot, trot_scenario

    table, presets = {}, {}
    for material in materials:
        rows = []
        for k in config.preset_candidates:
            run = simulate_trot(trot_scenario(material, distance=speed * config.sweep_duration + 1.0,
                                              payload_kg=config.payload_kg),
                                duration=config.sweep_duration, speed=speed, stiffness=k)
            judged = run.times >= config.sweep_judge_from
            rows.append({"stiffness_N_per_m": k, "fell": run.fell,
                         "vertical_acceleration_m_per_s2": spread(run.vertical_acceleration()[judged]),
                         "height_m": spread(run.states[judged, BASE_Z])})
        table[material] = rows
        best = min((r for r in rows if not r["fell"]), key=lambda r: r["vertical_acceleration_m_per_s2"]["iqr"])
        presets[material] = best["stiffness_N_per_m"]
    return {"speed_m_per_s": speed, "table": table, "presets": presets}


def vibration_case(models, material: str, speed: float, config: ExperimentConfig,
                   simulation_presets: dict | None = None) -> dict:
    """Fixed default stiffness against adaptive stiffness (the paper's presets and, if given,
    the simulation presets) on one material at one speed."""
    from qz_drake.classification.runs import simulate_trot, trot_scenario

    distance = speed * config.vibration_duration + 1.0
    runs, summary = {}, {"material": material, "speed_m_per_s": speed}
    variants = [("fixed 9 kN/m", "fixed", False, None), ("adaptive (paper presets)", "adaptive", True, None)]
    if simulation_presets:
        variants.append(("adaptive (simulation presets)", "adaptive_simulation_presets", True, simulation_presets))
    for label, key, adaptive, presets in variants:
        run = simulate_trot(trot_scenario(material, distance=distance, payload_kg=config.payload_kg),
                            duration=config.vibration_duration, speed=speed, models=models, adaptive=adaptive,
                            stiffness_by_material=presets)
        judged = run.times >= config.judge_from
        acceleration = run.vertical_acceleration()
        height = run.states[:, BASE_Z]
        runs[label] = {"times": run.times, "vertical_acceleration": acceleration, "height": height,
                       "judged": judged}
        summary[key] = {
            "fell": run.fell,
            "vertical_acceleration_m_per_s2": spread(acceleration[judged]),
            "height_m": spread(height[judged]),
            "final_stiffness_N_per_m": run.stiffness[-1].tolist(),
            "final_labels": [run.classes[int(c)] if c >= 0 else None for c in run.terrain_label[-1]],
        }
    # How much adaptive stiffness narrows the boxes (positive: less vibration). [%]
    for variant in [key for _, key, adaptive, _ in variants if adaptive]:
        prefix = "" if variant == "adaptive" else "simulation_presets_"
        for key, quantity in (("acceleration", "vertical_acceleration_m_per_s2"), ("height", "height_m")):
            for measure in ("iqr", "std"):
                fixed = summary["fixed"][quantity][measure]
                adaptive = summary[variant][quantity][measure]
                summary[f"{prefix}{key}_{measure}_reduction_percent"] = (
                    float(100.0 * (fixed - adaptive) / fixed) if fixed > 0 else 0.0)
    return {"summary": summary, "runs": runs}


def stance_label_scores(stance_leg, stance_truth, confirmed, *, confirmations: int = CONFIRMATIONS) -> dict:
    """Scores of the confirmed labels leg by leg, stance by stance, that separate the
    classifier's errors from the delay its confirmation rule builds in.

    ``confirmed`` is each stance's leg's confirmed label just after that stance ended. A stance
    is *settled* when its leg's last ``confirmations`` stances stood on the same known
    material (the rule could have switched by then); ``settled_accuracy`` is the share of
    settled stances whose confirmed label is that material. At every change of the material
    under a leg, ``switch_latency_stances`` counts the stances from the first one on the new
    material to the first whose confirmed label names it (``confirmations`` at best; a
    switch that never comes before the material changes again is counted in ``missed_switches``).
    """
    stance_leg, stance_truth, confirmed = (np.asarray(a, dtype=int) for a in (stance_leg, stance_truth, confirmed))
    settled_hits, latencies, missed = [], [], 0
    for leg in range(NUM_LEGS):
        truth, label = stance_truth[stance_leg == leg], confirmed[stance_leg == leg]
        for k in range(confirmations - 1, len(truth)):
            window = truth[k - confirmations + 1:k + 1]
            if window[0] >= 0 and np.all(window == window[0]):
                settled_hits.append(label[k] == truth[k])
        changes = [k for k in range(1, len(truth)) if truth[k] != truth[k - 1] and truth[k] >= 0]
        for n, k in enumerate(changes):
            end = changes[n + 1] if n + 1 < len(changes) else len(truth)
            hits = np.flatnonzero(label[k:end] == truth[k])
            if len(hits):
                latencies.append(int(hits[0]) + 1)
            elif end < len(truth):
                missed += 1
    return {"settled_accuracy": float(np.mean(settled_hits)) if settled_hits else None,
            "settled_stances": len(settled_hits),
            "switch_latency_stances": latencies,
            "median_switch_latency_stances": float(np.median(latencies)) if latencies else None,
            "missed_switches": missed}


def mixed_floor(models, config: ExperimentConfig, *, meshcat=None) -> dict:
    """Per-leg confirmed labels against the material under each foot on a striped floor."""
    from qz_drake.classification.runs import simulate_trot, trot_scenario

    distance = config.mixed_speed * config.mixed_duration + 1.0
    scenario = trot_scenario("concrete", distance=distance, payload_kg=config.payload_kg,
                             mixed_patch_length=config.mixed_patch_length)
    run = simulate_trot(scenario, duration=config.mixed_duration, speed=config.mixed_speed, models=models,
                        adaptive=True, meshcat=meshcat)
    labels, truth = run.terrain_label, run.ground_truth
    per_leg = {}
    for leg in range(NUM_LEGS):
        # Judged once the leg has confirmed a first terrain, where the truth is known.
        started = np.flatnonzero(labels[:, leg] >= 0)
        valid = np.zeros(len(labels), dtype=bool)
        if len(started):
            valid[started[0]:] = True
        valid &= truth[:, leg] >= 0
        per_leg[LEG_NAMES[leg]] = float(np.mean(labels[valid, leg] == truth[valid, leg])) if valid.any() else None
    scored = [v for v in per_leg.values() if v is not None]
    known = run.stance_truth >= 0
    # Each stance's leg's confirmed label at the logged sample of the stance's end.
    at_end = np.clip(np.searchsorted(run.times, run.stance_time, side="right") - 1, 0, len(run.times) - 1)
    confirmed = labels[at_end, run.stance_leg]
    return {"summary": {
        "speed_m_per_s": config.mixed_speed, "patch_length_m": config.mixed_patch_length,
        "distance_m": float(run.states[-1, BASE_POS][0] - run.states[0, BASE_POS][0]), "fell": run.fell,
        "label_accuracy_per_leg": per_leg,
        "mean_label_accuracy": float(np.mean(scored)) if scored else None,
        "stance_prediction_accuracy": float(np.mean(run.stance_prediction[known] == run.stance_truth[known]))
        if known.any() else None,
        **stance_label_scores(run.stance_leg, run.stance_truth, confirmed),
        "stances": int(len(run.stance_leg))}, "run": run}


def run_experiments(models_path, out_dir, config: ExperimentConfig | None = None, *, progress: bool = True) -> dict:
    """All experiments; writes the box plots, the label timeline and ``experiment.json``."""
    from qz_drake.classification.plots import plot_label_timeline, plot_vibration_boxes
    from qz_drake.classification.svm import load_models

    config = config or ExperimentConfig()
    models, _ = load_models(models_path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = {"config": dataclasses.asdict(config), "vibration": [], "files": {}}
    presets = None
    # Steps: the preset sweep (if any), each vibration case, the mixed floor.
    steps = bool(config.preset_candidates) + len(config.vibration_cases) + 1
    traces = {}
    with ProgressReport("classify experiment", steps, unit="steps", enabled=progress) as report:
        if config.preset_candidates:
            report.update(status="preset sweep")
            sweep = preset_sweep(sorted({m for m, _ in config.vibration_cases}), config)
            result["preset_sweep"] = sweep
            presets = sweep["presets"]
            report.update(advance=1)
        for material, speed in config.vibration_cases:
            report.update(status=f"vibration: {material} at {speed} m/s, fixed and adaptive")
            case = vibration_case(models, material, speed, config, presets)
            result["vibration"].append(case["summary"])
            traces[f"{material}, {speed} m/s"] = case["runs"]
            report.update(advance=1)
        report.update(status="mixed floor")
        mixed = mixed_floor(models, config)
        report.update(advance=1, status="done")
    result["files"]["acceleration_boxplot"] = str(plot_vibration_boxes(
        traces, out / "vibration_acceleration.png"))
    result["files"]["height_boxplot"] = str(plot_vibration_boxes(
        traces, out / "vibration_height.png", quantity="height", unit="m"))
    result["mixed_floor"] = mixed["summary"]
    run = mixed["run"]
    result["files"]["label_timeline"] = str(plot_label_timeline(run.times, run.terrain_label, run.ground_truth,
                                                                run.classes, out / "mixed_floor_labels.png"))
    (out / "experiment.json").write_text(json.dumps(result, indent=2))
    result["files"]["json"] = str(out / "experiment.json")
    return result
