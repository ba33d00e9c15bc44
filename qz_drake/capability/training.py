"""Training the 18 capability networks (paper 000 section II-E.1 and III-B; issue #13).

Protocol:

* rows are split by scene, never by trial: the scene ids are shuffled with the seed and cut
  70 / 15 / 15 into train / validation / test scenes, one split shared by all 18 networks, so
  no heading of a test scene was seen by any network (the paper's 72 headings per scene are
  near-duplicates of each other: a split by trial would score memory, not generalisation);
* each network is trained twice from the same seeded initialisation, with the paper's MSE
  loss on the sigmoid output and with binary cross-entropy; each run stops early on its own
  validation loss (the best epoch's weights are kept), and the run with the lower
  validation Brier score is kept (``select_by``), see :class:`TrainingConfig`;
* the kept network and the baselines of qz_drake.capability.evaluation (base rate, logistic
  regression, gradient boosting) are scored on the test scenes.

A (topology, kind) with too few training trials, or with one class only, gets no network: it
is listed in ``TrainingResult.missing`` with the reason, and the model refuses queries for it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time

import numpy as np

from qz_drake.capability.dataset import REQUIRED_KEYS, check_arrays
from qz_drake.capability.evaluation import (EvaluationConfig, baseline_inputs, baseline_metrics, beats_baselines,
                                            binary_metrics)
from qz_drake.capability.patches import KINDS, PATCH_SIZE, mirror_inputs
from qz_drake.errors import ConfigError, bad_value
from qz_drake.progress import ProgressReport
from qz_drake.robot.topology import TOPOLOGY_NAMES

LOSSES = ("mse", "bce")
# Seed offset between an ensemble's members (a prime, so members never share another
# network's seed: networks are seeded by their place among the 18).
ENSEMBLE_SEED_STEP = 7919
INITIALISATIONS = ("scratch", "pooled")
# The 18 networks (topology, kind), in TOPOLOGY_NAMES x KINDS order.
ALL_NETWORKS: tuple[tuple[str, str], ...] = tuple((t, k) for t in TOPOLOGY_NAMES for k in KINDS)


@dataclasses.dataclass
class TrainingConfig:
    """How the networks are trained and evaluated; saved in every network card."""

    # Seed of the scene split, the initialisations and the batch order.
    seed: int = 0
    # Fractions of the scenes for train / validation / test (issue #13: about 70 / 15 / 15).
    split: list[float] = dataclasses.field(default_factory=lambda: [0.70, 0.15, 0.15])
    # Losses to train with; the one better calibrated on validation is kept. "mse" is the
    # paper's (on the sigmoid output), "bce" binary cross-entropy.
    losses: list[str] = dataclasses.field(default_factory=lambda: ["mse", "bce"])
    # Validation metric that picks the loss: "brier" (a proper score: calibration plus
    # sharpness; a constant base-rate predictor has ECE near 0 but a poor Brier score) or "ece".
    select_by: str = "brier"
    # Most epochs per run; early stopping usually ends a run well before.
    max_epochs: int = 200
    # Epochs without a better validation loss before a run stops.
    patience: int = 15
    # Trials per gradient step.
    batch_size: int = 128
    # Adam step size.
    learning_rate: float = 2e-3
    # Adam's L2 weight decay. The networks are small, but a network sees one trial per
    # training scene (a few hundred to a thousand): measured on the first 5847 trials
    # (2026-12-02, BENCHMARKS "capability-networks", mirrored training, two scene splits),
    # 1e-2 against 1e-4 took the mean test AUC 0.869 -> 0.886 and 0.829 -> 0.860, the Brier
    # 0.131 -> 0.123 and 0.148 -> 0.135.
    weight_decay: float = 1e-2
    # Fewest training trials (and fewest of each class) for a network to be trained at all.
    min_train_trials: int = 40
    min_train_per_class: int = 5
    # Initialisations each loss is trained from; the run (loss, initialisation) with the best
    # validation score is kept. "scratch": the seeded random weights; "pooled": the weights of
    # one network of the same kind trained on the training trials of all six topologies (the
    # trials are paired: every scene, heading and start is tried in each topology, so the
    # pooled network sees six times the terrain; the topology network then fine-tunes it).
    # Measured on the first 3600 trials (2026-12-02, BENCHMARKS "capability-networks"): with
    # both, mean test AUC 0.71 against 0.70 and Brier 0.204 against 0.198, within the noise of
    # 28 test trials a network; the paper's from-scratch training stays the default.
    initialisations: list[str] = dataclasses.field(default_factory=lambda: ["scratch"])
    # Train on every training trial and on its mirror image (patches.mirror_inputs: the
    # same action on the terrain mirrored across the heading, same label; Qingzhui, its six
    # topologies and the tripod are symmetric about the sagittal plane, so the mirrored trial
    # is the trial of the mirrored scene). Validation and test rows are never mirrored.
    # Measured on the first 5847 trials (2026-12-02, BENCHMARKS "capability-networks"), two
    # scene splits, weight decay 1e-4: mean test AUC 0.855 -> 0.869 and 0.793 -> 0.829, Brier
    # 0.141 -> 0.131 and 0.153 -> 0.148.
    mirror: bool = True
    # Two outputs per network, the success and P(the BLC plans the move), trained on the
    # trials' success and blc_success labels (networks.NetworkConfig.factored);
    # the planner needs the first per state to tell a plan not found (the robot stands) from a
    # fall. False: the paper's single success output.
    factored: bool = True
    # Three outcomes as one softmax (networks.NetworkConfig.outcomes, issue 37): walked, no
    # plan, executed and failed, trained on the same two labels (success; blc_success).
    # "mse" is then the multi-class Brier score of the softmax, "bce" the cross-entropy.
    outcomes: bool = True
    # Members of each network's deep ensemble (networks.CapabilityEnsemble, issue 37): the
    # loss and initialisation are chosen on the first member's runs, and the others are
    # trained the same way from other seeds (their own initial weights and batch order). 1:
    # a single network.
    ensemble: int = 5
    # Networks to train, "topology/kind" names; empty: every (topology, kind) with data.
    networks: list[str] = dataclasses.field(default_factory=list)
    # Calibration bins and baseline features.
    evaluation: EvaluationConfig = dataclasses.field(default_factory=EvaluationConfig)

    def check(self) -> "TrainingConfig":
        if len(self.split) != 3 or any(not (f >= 0) for f in self.split) or not math.isclose(sum(self.split), 1.0):
            raise bad_value("training.split", self.split, "expected three fractions >= 0 summing to 1")
        if min(self.split[:2]) <= 0:
            raise bad_value("training.split", self.split, "train and validation fractions must be positive")
        for loss in self.losses:
            if loss not in LOSSES:
                raise bad_value("training.losses", self.losses, f"expected a list of {', '.join(LOSSES)}")
        if not self.losses:
            raise bad_value("training.losses", self.losses, "give at least one loss")
        if not self.initialisations or any(i not in INITIALISATIONS for i in self.initialisations):
            raise bad_value("training.initialisations", self.initialisations,
                            f"expected a non-empty list of {', '.join(INITIALISATIONS)}")
        for name in ("mirror", "factored", "outcomes"):
            if not isinstance(getattr(self, name), bool):
                raise bad_value(f"training.{name}", getattr(self, name), "expected true or false")
        if self.select_by not in ("brier", "ece"):
            raise bad_value("training.select_by", self.select_by, "expected brier or ece")
        for name in ("max_epochs", "patience", "batch_size", "min_train_trials", "min_train_per_class", "ensemble"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise bad_value(f"training.{name}", value, "must be a positive whole number")
        if not (self.learning_rate > 0 and self.weight_decay >= 0):
            raise bad_value("training.learning_rate", self.learning_rate, "must be positive (weight_decay >= 0)")
        if int(self.evaluation.ece_bins) < 2:
            raise bad_value("training.evaluation.ece_bins", self.evaluation.ece_bins, "must be at least 2")
        for name in self.networks:
            topology, _, kind = name.partition("/")
            if topology not in TOPOLOGY_NAMES or kind not in KINDS:
                raise bad_value("training.networks", name, "expected topology/kind, e.g. nominal/orthogonal")
        return self


def network_name(topology: str, kind: str) -> str:
    """``topology/kind``, the name of one network in cards and errors."""
    return f"{topology}/{kind}"


@dataclasses.dataclass
class NetworkResult:
    """One trained network and its card (config, loss choice, validation and test metrics)."""

    topology: str
    kind: str
    # The trained CapabilityNet (a torch module).
    net: object
    card: dict


@dataclasses.dataclass
class TrainingResult:
    """The networks of one training run and what it was trained on."""

    # (topology, kind) -> NetworkResult
    networks: dict
    # "topology/kind" -> why there is no network
    missing: dict[str, str]
    # "train" / "validation" / "test" -> scene ids
    split: dict[str, list[int]]
    fingerprint: str
    fingerprints: dict[str, str]
    config: TrainingConfig


def split_scenes(scene_ids, fractions=(0.70, 0.15, 0.15), seed: int = 0) -> dict[str, np.ndarray]:
    """Shuffles the distinct scene ids with the seed and cuts them by the fractions.

    Every split with a positive fraction gets at least one scene where there are enough;
    fewer than three scenes is an error (no honest test set).
    """
    scenes = np.unique(np.asarray(scene_ids, dtype=np.int64))
    if len(scenes) < 3:
        raise bad_value("dataset.scene", scenes.tolist(), "a split by scene needs at least three scenes")
    order = np.random.default_rng(seed).permutation(scenes)
    counts = np.floor(np.asarray(fractions, dtype=float) * len(scenes)).astype(int)
    counts = np.where((np.asarray(fractions) > 0) & (counts == 0), 1, counts)
    counts[0] = len(scenes) - counts[1:].sum()
    cuts = np.cumsum(counts)[:-1]
    train, val, test = np.split(order, cuts)
    return {"train": np.sort(train), "validation": np.sort(val), "test": np.sort(test)}


def _tensors(arrays: dict, rows: np.ndarray, kind: str, mirror: bool = False):
    """(patches, second head, labels) of the rows, labels (N, 2): the BLC planned the move
    (``blc_success``), the trial succeeded; with ``mirror``, followed by the rows' mirror
    images (patches.mirror_inputs) with the same labels."""
    import torch

    patch = np.asarray(arrays["patch"][rows], dtype=np.float32)
    feet = np.asarray(arrays["feet"][rows], dtype=np.float32)
    direction = np.asarray(arrays["direction"][rows])
    label = np.column_stack([np.asarray(arrays["blc_success"][rows], dtype=np.float32),
                             np.asarray(arrays["success"][rows], dtype=np.float32)])
    if mirror:
        m_patch, m_feet, m_direction = mirror_inputs(patch, feet, direction, kind)
        patch, feet = np.concatenate([patch, m_patch]), np.concatenate([feet, m_feet])
        direction, label = np.concatenate([direction, m_direction]), np.concatenate([label, label])
    extra = feet.reshape(len(patch), -1)
    if kind == "turn":
        extra = np.column_stack([extra, direction.astype(np.float32)])
    return torch.as_tensor(patch), torch.as_tensor(np.ascontiguousarray(extra)), torch.as_tensor(label)


def _split_tensors(arrays: dict, rows: dict[str, np.ndarray], kind: str, config: TrainingConfig) -> dict:
    """The tensors of each split; the train split mirrored when ``config.mirror``."""
    return {split: _tensors(arrays, r, kind, mirror=config.mirror and split == "train")
            for split, r in rows.items()}


# The three outcomes' order in a three-outcome network's output.
OUTCOMES = ("walked", "no_plan", "failed")


def outcome_classes(success, blc_success) -> np.ndarray:
    """Each sample's outcome as an index into OUTCOMES: walked (success), no plan (the BLC did
    not plan it), or executed and failed."""
    success, planned = np.asarray(success, dtype=bool), np.asarray(blc_success, dtype=bool)
    return np.where(success, 0, np.where(planned, 2, 1))


def _loss(name: str, logits, labels):
    """The loss of logits (B,) against the success labels; of factored logits (B, 2): the
    success output's against ``success`` plus the plan output's against ``blc_success``; of
    three-outcome logits (B, 3): the cross-entropy ("bce") or multi-class Brier score ("mse")
    against the outcome (labels (B, 2) are blc_success, success)."""
    import torch

    if logits.dim() == 2 and logits.shape[1] == 3:
        target = torch.where(labels[:, 1] > 0.5, 0, torch.where(labels[:, 0] > 0.5, 2, 1))
        if name == "mse":
            onehot = torch.nn.functional.one_hot(target, 3).to(logits.dtype)
            return ((torch.softmax(logits, dim=1) - onehot) ** 2).sum(dim=1).mean()
        return torch.nn.functional.cross_entropy(logits, target)

    def term(x, y):
        if name == "mse":
            return (torch.sigmoid(x) - y) ** 2
        return torch.nn.functional.binary_cross_entropy_with_logits(x, y, reduction="none")

    if logits.dim() == 1:
        return term(logits, labels[:, 1]).mean()
    return (term(logits[:, 0], labels[:, 1]) + term(logits[:, 1], labels[:, 0])).mean()


def _fit(kind: str, train, val, loss: str, config: TrainingConfig, seed: int, advance=None,
         initial_state: dict | None = None):
    """One training run, from the seeded random weights or ``initial_state`` (weights and
    input scaling of a pooled network); returns (net with the best validation epoch's weights,
    best epoch, epochs run)."""
    import torch

    from qz_drake.capability.networks import CapabilityNet, NetworkConfig

    torch.manual_seed(seed)
    net = CapabilityNet(kind, NetworkConfig(factored=config.factored, outcomes=config.outcomes))
    if initial_state is None:
        net.set_input_scaling(train[0], train[1])
    else:
        net.load_state_dict(initial_state)
    optimiser = torch.optim.Adam(net.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    generator = torch.Generator().manual_seed(seed)
    n = len(train[2])
    best, best_epoch, best_state, epoch = math.inf, 0, None, 0
    for epoch in range(1, config.max_epochs + 1):
        net.train()
        for batch in torch.randperm(n, generator=generator).split(config.batch_size):
            optimiser.zero_grad()
            _loss(loss, net(train[0][batch], train[1][batch]), train[2][batch]).backward()
            optimiser.step()
        net.eval()
        with torch.no_grad():
            value = float(_loss(loss, net(val[0], val[1]), val[2]))
        if advance is not None:
            advance(1)
        if value < best - 1e-6:
            best, best_epoch = value, epoch
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        elif epoch - best_epoch >= config.patience:
            break
    net.load_state_dict(best_state)
    net.eval()
    return net, best_epoch, epoch


def _predict(net, data) -> np.ndarray:
    import torch

    with torch.no_grad():
        return net.probability(data[0], data[1]).numpy().astype(float)


def _why_missing(labels: np.ndarray, config: TrainingConfig, n_val: int) -> str | None:
    positives = int(labels.sum())
    if len(labels) < config.min_train_trials:
        return f"{len(labels)} training trials (need {config.min_train_trials})"
    if min(positives, len(labels) - positives) < config.min_train_per_class:
        return (f"{positives} successes and {len(labels) - positives} failures in training "
                f"(need {config.min_train_per_class} of each)")
    if n_val == 0:
        return "no validation trials"
    return None


def pooled_states(arrays: dict, rows: dict[str, np.ndarray], kind: str, config: TrainingConfig,
                  seed: int) -> dict[str, dict]:
    """loss -> the state of one network of ``kind`` trained on the given (all topologies')
    train rows, early-stopped on their validation rows: the "pooled" initialisation."""
    data = _split_tensors(arrays, {s: r for s, r in rows.items() if s != "test"}, kind, config)
    out = {}
    for loss in config.losses:
        net, _, _ = _fit(kind, data["train"], data["validation"], loss, config, seed)
        out[loss] = {k: v.detach().clone() for k, v in net.state_dict().items()}
    return out


def train_one(arrays: dict, rows: dict[str, np.ndarray], topology: str, kind: str, config: TrainingConfig,
              seed: int, advance=None, pooled: dict | None = None) -> NetworkResult:
    """Trains one network on its train rows with each loss and initialisation (``pooled``:
    loss -> state of the pooled network of its kind), keeps the run that scores best on
    validation and scores it and the baselines on its test rows."""
    bins = int(config.evaluation.ece_bins)
    data = _split_tensors(arrays, rows, kind, config)
    runs = {}
    for loss in config.losses:
        for init in config.initialisations:
            if init == "pooled" and not (pooled and loss in pooled):
                continue
            start = time.perf_counter()
            net, best_epoch, epochs = _fit(kind, data["train"], data["validation"], loss, config, seed, advance,
                                           initial_state=pooled[loss] if init == "pooled" else None)
            val = binary_metrics(data["validation"][2][:, 1].numpy(), _predict(net, data["validation"]), bins=bins)
            name = loss if init == "scratch" else f"{loss}+pooled"
            runs[name] = (net, {"loss": loss, "initialisation": init, "best_epoch": best_epoch, "epochs": epochs,
                                "train_seconds": time.perf_counter() - start, "validation": val})
    order = list(runs)
    chosen = min(runs, key=lambda r: (runs[r][1]["validation"][config.select_by], order.index(r)))
    net = runs[chosen][0]
    members = []
    if config.ensemble > 1:
        from qz_drake.capability.networks import CapabilityEnsemble

        loss, init = runs[chosen][1]["loss"], runs[chosen][1]["initialisation"]
        members = [net]
        for m in range(1, config.ensemble):
            member, _, _ = _fit(kind, data["train"], data["validation"], loss, config, seed + ENSEMBLE_SEED_STEP * m,
                                advance, initial_state=pooled[loss] if init == "pooled" else None)
            members.append(member)
        net = CapabilityEnsemble(members).eval()
    test_labels = np.asarray(arrays["success"][rows["test"]], dtype=bool)
    test = binary_metrics(test_labels, _predict(net, data["test"]), bins=bins)
    if net.factored:  # how well the plan output tells what the BLC plans (the planner's stand)
        import torch

        with torch.no_grad():
            planned = net.plan_probability(data["test"][0], data["test"][1]).numpy().astype(float)
        test["plan"] = binary_metrics(np.asarray(arrays["blc_success"][rows["test"]], dtype=bool), planned, bins=bins)
    if getattr(net, "outcomes", False):  # the three outcomes on the test rows, against their base rates
        test["outcomes"] = outcome_metrics(net, data["test"], arrays, rows, bins)
    if members:  # the ensemble's mean against its first member alone, and how much they disagree
        import torch

        with torch.no_grad():
            spread = net.spread(data["test"][0], data["test"][1]).numpy()
        test["first_member"] = binary_metrics(test_labels, _predict(members[0], data["test"]), bins=bins)
        test["spread"] = {"mean": float(spread.mean()) if len(spread) else None,
                          "p90": float(np.quantile(spread, 0.9)) if len(spread) else None}
    features = {split: baseline_inputs(arrays["patch"][r], arrays["direction"][r], kind, config.evaluation)
                for split, r in rows.items() if split in ("train", "test")}
    baselines = baseline_metrics(features["train"], arrays["success"][rows["train"]], features["test"],
                                 test_labels, bins=bins, seed=seed)
    others = [loss for loss in runs if loss != chosen]
    reason = (f"validation {config.select_by} {runs[chosen][1]['validation'][config.select_by]:.4f} against "
              + ", ".join(f"{o} {runs[o][1]['validation'][config.select_by]:.4f}" for o in others)
              if others else "the only loss trained")
    card = {
        "topology": topology, "kind": kind, "loss": runs[chosen][1]["loss"],
        "initialisation": runs[chosen][1]["initialisation"], "run": chosen, "loss_reason": reason,
        "runs": {loss: info for loss, (_, info) in runs.items()},
        "n": {split: int(len(r)) for split, r in rows.items()},
        # Rows the network was fitted on: the training trials, and their mirror images.
        "train_rows": int(len(data["train"][2])),
        "positives": {split: int(np.sum(arrays["success"][r])) for split, r in rows.items()},
        # The training trials' failures by what failed: the BLC found no plan (the robot stood
        # where it was) or the walk failed the verdict (a fall, a leg in the terrain, a slip, a
        # missed target). The planner's MDP reads the share of the first as a failure that
        # leaves the robot standing (qz_drake.planning.capability_mdp, plan_failure_share).
        "failures": _failure_counts(arrays, rows["train"]),
        "test": test, "baselines": baselines,
        "beats_baselines": beats_baselines(test, baselines),
        "seed": seed,
        # Members of the network's ensemble (1: a single network).
        "ensemble_members": max(1, len(members)),
    }
    return NetworkResult(topology, kind, net, card)


def outcome_metrics(net, data, arrays: dict, rows: dict, bins: int) -> dict:
    """A three-outcome network on the test rows: its multi-class Brier score and log loss
    against the training rows' outcome frequencies as a constant prediction, and "executed
    and failed" scored as a binary prediction (what ends a walk)."""
    import torch

    with torch.no_grad():
        probs = net.outcome_probabilities(data[0], data[1]).numpy().astype(float)
    test = outcome_classes(arrays["success"][rows["test"]], arrays["blc_success"][rows["test"]])
    train = outcome_classes(arrays["success"][rows["train"]], arrays["blc_success"][rows["train"]])
    prior = (np.bincount(train, minlength=3) + 0.5) / (len(train) + 1.5)

    return {"counts": {name: int(np.sum(test == i)) for i, name in enumerate(OUTCOMES)},
            "network": outcome_scores(probs, test),
            "base_rate": outcome_scores(np.broadcast_to(prior, probs.shape), test),
            "failed": binary_metrics(test == 2, probs[:, 2], bins=bins)}


def outcome_scores(probs, labels) -> dict:
    """Proper scores of three-outcome probabilities (n, 3) against outcome indices (n,): the
    multi-class Brier score and the log loss."""
    onehot = np.eye(3)[labels]
    return {"brier": float(np.mean(np.sum((probs - onehot) ** 2, axis=1))),
            "log_loss": float(-np.mean(np.log(np.clip(probs[np.arange(len(labels)), labels], 1e-12, 1.0))))}


def _failure_counts(arrays: dict, rows: np.ndarray) -> dict[str, int]:
    failed = ~np.asarray(arrays["success"][rows], dtype=bool)
    planned = np.asarray(arrays["blc_success"][rows], dtype=bool)
    return {"planning": int(np.sum(failed & ~planned)), "execution": int(np.sum(failed & planned))}


def dataset_digest(arrays: dict) -> str:
    """SHA-256 of the arrays the networks learn from (REQUIRED_KEYS): two datasets with the
    same fingerprints but other trials (a collection that went on) differ here."""
    digest = hashlib.sha256()
    for key in REQUIRED_KEYS:
        array = np.ascontiguousarray(arrays[key])
        digest.update(f"{key}:{array.dtype.str}:{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


# The modules whose code decides what a trained network is.
TRAINING_MODULES = ("qz_drake.capability.training", "qz_drake.capability.networks",
                    "qz_drake.capability.evaluation", "qz_drake.capability.patches")


def training_identity(arrays: dict, *, fingerprint: str, fingerprints: dict | None,
                      config: TrainingConfig) -> dict:
    """What makes two trainings the same one, so that a resumed training never mixes in a
    network of another: the dataset (its digest and fingerprints), every setting but the list
    of networks (a network is the same whether trained alone or with the rest: it is seeded by
    its place among the 18) and the training code (syntax trees, comments and docstrings
    aside). JSON-ready."""
    from qz_drake.capability.dataset import _code_hash

    settings = dataclasses.asdict(config)
    settings.pop("networks")
    code = hashlib.sha256("\n".join(f"{m}:{_code_hash(m)}" for m in TRAINING_MODULES).encode()).hexdigest()[:16]
    return {"dataset_digest": dataset_digest(arrays), "fingerprint": fingerprint,
            "fingerprints": dict(fingerprints or {}), "training_config": settings, "training_code": code}


def train_networks(arrays: dict, *, fingerprint: str, fingerprints: dict | None = None,
                   config: TrainingConfig | None = None, progress: bool = False, finished: dict | None = None,
                   on_network=None) -> TrainingResult:
    """Trains every (topology, kind) network the arrays have data for.

    Args:
        arrays: the dataset contract's arrays (one row per executed trial).
        fingerprint: the dataset manifest's fingerprint of what produced the labels; it goes
            into every card and a loaded model is checked against it.
        fingerprints: the manifest's per-component fingerprints (robot, blc, controller,
            verdict), kept so that ``evaluate`` can name the component that differs.
        config: training protocol; defaults in :class:`TrainingConfig`.
        progress: networks done of the total, with an ETA, on stderr (qz_drake.progress).
        finished: (topology, kind) -> NetworkResult of this same training, done before it was
            interrupted (qz_drake.capability.model.unfinished_networks): taken as they are,
            not trained again.
        on_network: called with each NetworkResult as soon as it is trained (to save it, so
            that an interrupted training keeps what it finished).
    """
    config = (config or TrainingConfig()).check()
    if not isinstance(fingerprint, str) or not fingerprint:
        raise bad_value("dataset.manifest.fingerprint", fingerprint, "expected a non-empty string")
    check_arrays(arrays)
    # Topology switches (an episode dataset's kind "switch", issue 37) are samples of their
    # own, for the tables of where a switch succeeds; no network learns them.
    switches = np.asarray(arrays["kind"]).astype(str) == "switch"
    if switches.any():
        arrays = {key: (np.asarray(value)[~switches] if np.ndim(value) and len(value) == len(switches) else value)
                  for key, value in arrays.items()}
    split = split_scenes(arrays["scene"], config.split, config.seed)
    scene = np.asarray(arrays["scene"], dtype=np.int64)
    in_split = {name: np.isin(scene, ids) for name, ids in split.items()}
    topology, kind = np.asarray(arrays["topology"]).astype(str), np.asarray(arrays["kind"]).astype(str)
    wanted = [tuple(n.split("/")) for n in config.networks] or list(ALL_NETWORKS)
    unknown = sorted(set(np.unique(topology)) - set(TOPOLOGY_NAMES)) + sorted(set(np.unique(kind)) - set(KINDS))
    if unknown:
        raise bad_value("dataset.topology/kind", unknown, "not a topology or network kind of qz_drake")
    missing, plan = {}, []
    for t, k in wanted:
        # Seeded by its place among all 18, so a network trained alone is the one of a full run.
        index = ALL_NETWORKS.index((t, k))
        mask = (topology == t) & (kind == k)
        rows = {name: np.nonzero(mask & m)[0] for name, m in in_split.items()}
        why = _why_missing(np.asarray(arrays["success"][rows["train"]], dtype=bool), config, len(rows["validation"]))
        if why:
            missing[network_name(t, k)] = why
        else:
            plan.append((index, t, k, rows))
    for t, k in ALL_NETWORKS:
        if (t, k) not in wanted:
            missing[network_name(t, k)] = "not requested (training.networks)"
    if not plan:
        reasons = "; ".join(f"{network_name(t, k)}: {missing[network_name(t, k)]}" for t, k in wanted)
        raise ConfigError(f"dataset: no network has enough data to train ({reasons})")

    finished = {key: finished[key] for key in (finished or {}) if key in {(t, k) for _, t, k, _ in plan}}
    todo = [p for p in plan if (p[1], p[2]) not in finished]
    pooled: dict[str, dict] = {}
    if "pooled" in config.initialisations:
        for k in dict.fromkeys(k for _, _, k, _ in todo):
            mask = kind == k
            rows = {name: np.nonzero(mask & m)[0] for name, m in in_split.items()}
            pooled[k] = pooled_states(arrays, rows, k, config, config.seed + 1000 + KINDS.index(k))
    runs = len(config.losses) * len(config.initialisations) + config.ensemble - 1
    with ProgressReport("training networks", len(plan), unit="networks", completed=len(finished),
                        enabled=progress) as report:
        for index, t, k, rows in todo:
            epochs = [0]

            def advance(step, name=network_name(t, k), epochs=epochs):
                epochs[0] += step
                report.update(status=f"{name}: epoch {epochs[0]} (at most {config.max_epochs} x {runs} runs)")

            network = train_one(arrays, rows, t, k, config, config.seed + index, advance, pooled=pooled.get(k))
            if on_network is not None:
                on_network(network)
            finished[(t, k)] = network
            report.update(advance=1, status=f"{network_name(t, k)} done")
    # In the order of the plan, whichever of them came from an interrupted run.
    networks = {(t, k): finished[(t, k)] for _, t, k, _ in plan}
    return TrainingResult(networks=networks, missing=missing,
                          split={name: ids.tolist() for name, ids in split.items()},
                          fingerprint=fingerprint, fingerprints=dict(fingerprints or {}), config=config)
