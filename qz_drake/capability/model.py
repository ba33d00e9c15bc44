"""CapabilityModel: the 18 learned transition probabilities of paper 000 (section II-E.1).

A model directory holds, per network ``<topology>_<kind>``, the weights as safetensors (no
pickle; the header's metadata names the format, topology and kind) and a JSON card (dataset
fingerprint, training config, loss choice, validation and test metrics, baselines, the
weights' SHA-256); ``model.json`` is the top-level card (fingerprints, split, the networks and
the missing ones with why). Loading checks every card against the top card and every weights
file against its card: a file that is not ours, or a fingerprint that differs, is refused
with one QzError line.

Importing this module does not import torch; loading or building a model does.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from qz_drake.capability import patches as P
from qz_drake.capability.dataset import robot_fingerprint
# What every capability model shares, defined below the learners and re-exported here.
from qz_drake.capability.model_base import (FORMAT_VERSION, MODEL_CARD, MODEL_FORMAT,  # noqa: F401
                                            CapabilityMap, CapabilityModelBase, CapabilityModelError, MapInputs,
                                            _error, _replace, _sha256, _shares, check_direction, check_patches,
                                            distinct_rows, evaluate_map, predict_map, sample_map_inputs)
from qz_drake.threads import set_torch_threads, torch_device

NETWORK_FORMAT = "qz_drake.capability_network"
# Where the shipped model lives (trained by `qz capability train` on the real trial dataset).
DEFAULT_MODEL_DIR = Path(__file__).resolve().parents[1] / "data" / "capability_model"
# Queries per forward pass of one network. Small enough that the first convolution's output
# (4 channels x 20 x 20 floats a query, 6.5 MB) stays in the cache: measured 2026-12-02 on this
# 2-core EPYC (32 MB L3), one torch thread, 16 384 queries: 9-11 us a query at 256-1024, 22-28 us
# at 2048-8192 (the activations went to memory and back between layers).
INFERENCE_BATCH = 1024
# Queries per pass of CapabilityModel.success_all for six networks, whose first convolution has
# the kernels of all six topologies (24 channels, 9.8 MB at 256 queries): 43-46 us a query for
# the six topologies at 128-512, 99-111 us at 1024-4096 (the same measurement). With more
# networks stacked (ensembles: 6 x 5 members) a pass takes proportionally fewer queries, so
# that the activations stay in the cache: on the 20 m world, 30 stacked members took 2.3 s at
# 32-64 queries a pass against 3.8-5.0 s at 256 and 6.5-7.8 s at 1024 (2026-12-05, with the
# other core collecting).
INFERENCE_BATCH_ALL = 256


def file_stem(topology: str, kind: str) -> str:
    return f"{topology}_{kind}"


def _jsonable(value):
    if dataclasses.is_dataclass(value):
        return dataclasses.asdict(value)
    raise TypeError(type(value).__name__)


# What save_network writes around a network's own card (NetworkResult.card).
_CARD_WRAPPER = ("format", "version", "name", "fingerprint", "fingerprints", "weights", "weights_sha256",
                 "network_config", "training_config", "training_identity")
# The folder inside a model folder where a training keeps each network as it finishes; it
# becomes the model (model.json, the networks beside it) only when every network is done, so
# an interrupted retraining leaves the earlier model whole.
UNFINISHED_DIR = "unfinished_training"


def save_network(out_dir, network, *, fingerprint: str, fingerprints: dict, config: dict,
                 identity: dict | None = None) -> dict:
    """Writes one NetworkResult (qz_drake.capability.training) into ``out_dir``: its weights,
    then its card (so a card always describes weights that are complete); ``identity``
    (training.training_identity) goes into the card of an unfinished training. Returns the
    network's entry of model.json."""
    from safetensors.torch import save_file

    from qz_drake.capability.training import network_name

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = file_stem(network.topology, network.kind)
    weights = out / f"{stem}.safetensors"
    state = {k: v.detach().contiguous() for k, v in network.net.state_dict().items()}
    _replace(weights, lambda tmp: save_file(state, str(tmp), metadata={
        "format": NETWORK_FORMAT, "version": str(FORMAT_VERSION), "topology": network.topology, "kind": network.kind,
        "network_config": json.dumps(dataclasses.asdict(network.net.config)), "fingerprint": fingerprint}))
    card = {"format": NETWORK_FORMAT, "version": FORMAT_VERSION, "name": network_name(network.topology, network.kind),
            "fingerprint": fingerprint, "fingerprints": fingerprints,
            "weights": weights.name, "weights_sha256": _sha256(weights),
            "network_config": dataclasses.asdict(network.net.config), "training_config": config,
            **({"training_identity": identity} if identity is not None else {}), **network.card}
    _replace(out / f"{stem}.json", lambda tmp: tmp.write_text(json.dumps(card, indent=2, default=_jsonable)))
    return {"weights": weights.name, "card": f"{stem}.json"}


def save_model(result, out_dir) -> Path:
    """Writes a TrainingResult (qz_drake.capability.training) as a model directory; returns it."""
    from qz_drake.capability.training import network_name

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    config = dataclasses.asdict(result.config)
    entries = {network_name(topology, kind): save_network(out, network, fingerprint=result.fingerprint,
                                                          fingerprints=result.fingerprints, config=config)
               for (topology, kind), network in sorted(result.networks.items())}
    top = {"format": MODEL_FORMAT, "version": FORMAT_VERSION, "fingerprint": result.fingerprint,
           "fingerprints": result.fingerprints, "networks": entries, "missing": result.missing,
           "split": result.split, "training_config": config}
    (out / MODEL_CARD).write_text(json.dumps(top, indent=2, default=_jsonable))
    return out


def _first_difference(theirs, mine, path: str = ""):
    """(dotted key, theirs, mine) of the first entry where two JSON values differ, or None."""
    if isinstance(theirs, dict) and isinstance(mine, dict):
        for key in sorted(set(theirs) | set(mine)):
            found = _first_difference(theirs.get(key), mine.get(key), f"{path}.{key}" if path else key)
            if found:
                return found
        return None
    return None if theirs == mine else (path, theirs, mine)


def unfinished_networks(folder, identity: dict) -> dict:
    """(topology, kind) -> NetworkResult of the networks an interrupted training saved in
    ``folder`` (save_network with its ``identity``), for the same training to go on from.

    A card that records another training (another dataset, setting or training code; or none)
    is refused with a CapabilityModelError naming the first thing that differs: a resumed
    training never mixes two trainings. A network whose weights file is missing or does not
    match its card is left out (trained again).
    """
    from qz_drake.capability.training import ALL_NETWORKS, NetworkResult, network_name

    folder = Path(folder)
    mine = json.loads(json.dumps(identity, default=_jsonable))
    found = {}
    for topology, kind in ALL_NETWORKS:
        path = folder / f"{file_stem(topology, kind)}.json"
        if not path.is_file():
            continue
        name = network_name(topology, kind)
        card = _read_json(path, f"{UNFINISHED_DIR}.{name}")
        difference = _first_difference(card.get("training_identity"), mine)
        if difference is not None:
            field, theirs, ours = difference
            raise _error(f"{path}: training_identity.{field}" if field else f"{path}: training_identity", theirs,
                         f"the interrupted training there differs from this one ({ours!r}): rerun it with its own "
                         "arguments to finish it, use another --out, or pass --restart to discard it")
        try:
            net = load_network(folder / str(card.get("weights")), card, name)
        except CapabilityModelError:
            continue
        found[(topology, kind)] = NetworkResult(topology, kind, net,
                                                {k: v for k, v in card.items() if k not in _CARD_WRAPPER})
    return found


def _read_json(path: Path, field: str) -> dict:
    if not path.is_file():
        raise _error(field, str(path), "no such file")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise _error(field, str(path), f"not a JSON card ({e.__class__.__name__})") from None
    if not isinstance(data, dict):
        raise _error(field, str(path), "not a JSON card")
    return data


def load_network(weights: Path, card: dict, name: str):
    """One CapabilityNet from its safetensors file, checked against its card."""
    from safetensors import SafetensorError, safe_open

    from qz_drake.capability.networks import CapabilityNet, NetworkConfig

    field = f"model.networks.{name}.weights"
    if not weights.is_file():
        raise _error(field, str(weights), "no such file")
    try:
        with safe_open(str(weights), framework="pt") as f:
            metadata = f.metadata() or {}
            state = {k: f.get_tensor(k) for k in f.keys()}
    except (SafetensorError, OSError, ValueError) as e:
        raise _error(field, str(weights), f"not a safetensors file ({str(e).splitlines()[0][:80]})") from None
    topology, _, kind = name.partition("/")
    if metadata.get("format") != NETWORK_FORMAT or (metadata.get("topology"), metadata.get("kind")) != (topology, kind):
        raise _error(field, str(weights), f"not a qz_drake capability network for {name} "
                                          f"(header format {metadata.get('format')!r})")
    if card.get("weights_sha256") != _sha256(weights):
        raise _error(field, str(weights), "its SHA-256 differs from the card's weights_sha256 (file replaced?)")
    # Cards written before the factored output have one output, before issue 37 at most two.
    config = NetworkConfig(**{"factored": False, "outcomes": False, **card.get("network_config", {})})
    members = int(card.get("ensemble_members", 1))
    if members > 1:
        from qz_drake.capability.networks import CapabilityEnsemble

        net = CapabilityEnsemble([CapabilityNet(kind, config) for _ in range(members)])
    else:
        net = CapabilityNet(kind, config)
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise _error(field, str(weights), f"tensors do not fit the network ({str(e).splitlines()[0][:80]})") from None
    return net.eval()


class _StackedMembers:
    """Several CapabilityNets of one kind and layer sizes evaluated as one: their weights stacked
    (member m's in slice m), so that a batch of patches goes through all of them in a few large
    operations instead of many small ones (CapabilityModel.success_all)."""

    def __init__(self, nets):
        import torch

        first = nets[0]
        if any(n.config != first.config or n.kind != first.kind for n in nets):
            raise ValueError("stacked networks must share their kind and layer sizes")
        self.count = len(nets)
        self.width = first.conv1.out_channels
        self.pad = first.conv1.weight.shape[-1] // 2
        interior = [torch.conv2d(torch.ones(1, 1, P.PATCH_SIZE, P.PATCH_SIZE, device=n.conv1.weight.device),
                                 n.conv1.weight, padding=self.pad)[0] for n in nets]
        self.kernels1 = torch.cat([n.conv1.weight / n.patch_scale for n in nets])
        self.offsets1 = torch.cat([interior[i] * (n.patch_mean / n.patch_scale) - n.conv1.bias[:, None, None]
                                   for i, n in enumerate(nets)])
        self.weight2 = torch.cat([n.conv2.weight for n in nets])
        self.bias2 = torch.cat([n.conv2.bias for n in nets])
        self.patch_w = torch.stack([n.patch_dense.weight for n in nets])  # (M, F, C*25)
        self.patch_b = torch.stack([n.patch_dense.bias for n in nets])
        self.extra_mean = torch.stack([n.extra_mean for n in nets])  # (M, E)
        self.extra_scale = torch.stack([n.extra_scale for n in nets])
        self.w1 = torch.stack([n.dense1.weight for n in nets])  # (M, H, F + E)
        self.b1 = torch.stack([n.dense1.bias for n in nets])
        self.w2 = torch.stack([n.dense2.weight for n in nets])  # (M, O, H)
        self.b2 = torch.stack([n.dense2.bias for n in nets])
        self.outputs_count = first.dense2.out_features
        self.features_count = first.patch_dense.out_features

    def features(self, x):
        """(B, M, F) patch features of raw patches x (B, 1, 20, 20) [m]."""
        import torch

        from qz_drake.capability.networks import _max_pool_2x2

        h = torch.relu(_max_pool_2x2(torch.conv2d(x, self.kernels1, padding=self.pad) - self.offsets1))
        h = torch.relu(_max_pool_2x2(torch.conv2d(h, self.weight2, self.bias2, padding=self.pad, groups=self.count)))
        h = h.reshape(h.shape[0], self.count, -1)
        return torch.relu(torch.einsum("bmi,moi->bmo", h, self.patch_w) + self.patch_b)

    def outputs(self, features, extra):
        """(success (B, M), plan (B, M) or None) of each member, from its features (B, M, F) and
        its raw second head (B, M, E) [m, and d]."""
        import torch

        e = (extra - self.extra_mean) / self.extra_scale
        hidden = torch.relu(torch.einsum("bmi,moi->bmo", torch.cat([features, e], dim=2), self.w1) + self.b1)
        logits = torch.einsum("bmi,moi->bmo", hidden, self.w2) + self.b2
        if self.outputs_count == 3:
            p = torch.softmax(logits, dim=2)
            return p[..., 0], 1.0 - p[..., 1]
        if self.outputs_count == 2:
            return torch.sigmoid(logits[..., 0]), torch.sigmoid(logits[..., 1])
        return torch.sigmoid(logits[..., 0]), None


class CapabilityModel(CapabilityModelBase):
    """The success probabilities of forward moves and 45 deg turns in each topology.

    ``success(patches, feet, kind, topology, direction=None)`` evaluates one network on any
    number of queries in one call; :meth:`query_inputs` samples the inputs for (x, y,
    heading) queries straight from a HeightMap and :meth:`map_success` evaluates every cell
    and heading of a map for the planner (qz_drake.planning.capability_mdp).
    """

    def __init__(self, networks: dict, card: dict, device: str | None = None):
        # (topology, kind) -> CapabilityNet, in eval mode.
        self._networks = dict(networks)
        self.card = card
        # Inference on the cores that are free now (qz_drake/threads.py): torch's default of
        # one thread per core made a plan 3x slower with the other core busy.
        set_torch_threads()
        # Where the networks run (threads.torch_device: the CPU unless asked).
        self.device = "cpu"
        self.to(torch_device(device))

    def to(self, device: str) -> "CapabilityModel":
        """Moves every network to a torch device ("cpu", "cuda", "cuda:N"; see
        threads.torch_device); inputs and answers stay numpy arrays on the host."""
        if device != self.device:
            for net in self._networks.values():
                net.to(device)
            self.device = device
        return self

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def load(cls, path=None, *, fingerprint: str | None = None, device: str | None = None) -> "CapabilityModel":
        """Loads every network of a model directory (default: the shipped model).

        Args:
            path: a directory written by :func:`save_model` / ``qz capability train``.
            fingerprint: when given, the dataset fingerprint the model must have been trained on.
            device: where the networks run (threads.torch_device; None: ``QZ_TORCH_DEVICE``,
                else the CPU).
        """
        folder = Path(DEFAULT_MODEL_DIR if path is None else path)
        if not (folder / MODEL_CARD).is_file():
            hint = ("no model has been shipped yet: train one with `qz capability train --dataset DIR --out DIR` "
                    "and pass --model DIR" if path is None else f"no {MODEL_CARD} there (not a model directory)")
            raise _error("model", str(folder), hint)
        top = _read_json(folder / MODEL_CARD, "model")
        if top.get("format") != MODEL_FORMAT:
            raise _error("model.format", top.get("format"),
                         f"{folder / MODEL_CARD} is not a qz_drake capability model card")
        if top.get("version") != FORMAT_VERSION:
            raise _error("model.version", top.get("version"), f"this code reads version {FORMAT_VERSION}")
        if fingerprint is not None and top.get("fingerprint") != fingerprint:
            raise _error("model.fingerprint", top.get("fingerprint"), f"expected the dataset's {fingerprint!r}")
        # A model learned another robot's capability (its card names the robot code it was
        # trained with); one without robot fingerprints (a synthetic model) describes none.
        robot = top.get("fingerprints", {}).get("robot")
        if robot is not None and robot != robot_fingerprint():
            raise _error("model.fingerprints.robot", robot, "the model was trained on another robot configuration")
        if top.get("learner") == "boosted":  # one boosted ensemble for every network (capability/boosted.py)
            from qz_drake.capability.boosted import BoostedCapabilityModel

            return BoostedCapabilityModel.load_folder(folder, top, device)
        networks = {}
        for name, entry in top.get("networks", {}).items():
            card = _read_json(folder / entry["card"], f"model.networks.{name}.card")
            if card.get("format") != NETWORK_FORMAT or card.get("name") != name:
                raise _error(f"model.networks.{name}.card", str(folder / entry["card"]),
                             f"not the card of the {name} network")
            if card.get("fingerprint") != top.get("fingerprint"):
                raise _error(f"model.networks.{name}.fingerprint", card.get("fingerprint"),
                             f"differs from the model's {top.get('fingerprint')!r}: trained on other data")
            topology, _, kind = name.partition("/")
            networks[(topology, kind)] = load_network(folder / entry["weights"], card, name)
            top.setdefault("cards", {})[name] = card
        return cls(networks, top, device)

    @classmethod
    def from_training(cls, result) -> "CapabilityModel":
        """The model of a TrainingResult, without writing it."""
        from qz_drake.capability.training import network_name

        card = {"format": MODEL_FORMAT, "version": FORMAT_VERSION, "fingerprint": result.fingerprint,
                "fingerprints": result.fingerprints, "missing": dict(result.missing), "split": result.split,
                "networks": {network_name(*key): {} for key in result.networks},
                "cards": {network_name(*key): n.card for key, n in result.networks.items()}}
        return cls({key: n.net.eval() for key, n in result.networks.items()}, card)

    @classmethod
    def random(cls, *, seed: int = 0, topologies=None, kinds=P.KINDS) -> "CapabilityModel":
        """Untrained networks with seeded random weights: for timing and plumbing only."""
        import torch

        from qz_drake.capability.networks import CapabilityNet
        from qz_drake.robot.topology import TOPOLOGY_NAMES

        torch.manual_seed(seed)
        keys = [(t, k) for t in (topologies or TOPOLOGY_NAMES) for k in kinds]
        card = {"format": MODEL_FORMAT, "version": FORMAT_VERSION, "fingerprint": f"random-{seed}",
                "fingerprints": {}, "missing": {}, "random": True}
        return cls({key: CapabilityNet(key[1]).eval() for key in keys}, card)

    @property
    def identity(self) -> str:
        """Which trained weights these are: a digest of every network's weights SHA-256 (from
        the cards), so that two models trained on the same dataset still differ. A model
        without weight digests (random, or not saved) is its dataset fingerprint."""
        import hashlib

        cards = self.card.get("cards", {})
        digests = sorted((name, card.get("weights_sha256", "")) for name, card in cards.items())
        if not digests or not all(d for _, d in digests):
            return self.fingerprint
        return hashlib.sha256(repr(digests).encode()).hexdigest()[:16]

    def network(self, topology: str, kind: str):
        """The torch module of one network; an explicit error naming it when the model lacks it."""
        P.check_kind(kind)
        key = (topology, kind)
        if key not in self._networks:
            name = f"{topology}/{kind}"
            why = self.card.get("missing", {}).get(name)
            raise _error("model.networks", name, "this model has no such network"
                         + (f" (not trained: {why})" if why else ""))
        return self._networks[key]

    # -- inference ----------------------------------------------------------------------------
    def success(self, patches, feet, kind: str, topology: str, direction=None) -> np.ndarray:
        """Success probabilities of one network for any number of queries, as float64.

        Args:
            patches: (..., 20, 20) height patches relative to the standing ground [m]
                (patches.sample_patches of this kind).
            feet: (..., 6, 3) start feet in the heading frame [m] (patches.feet_in_heading_frame).
            kind: orthogonal, diagonal or turn.
            topology: one of TOPOLOGY_NAMES.
            direction: for turns, d (0 left, 1 right), broadcast to the queries; None for moves.
        """
        import torch

        net = self.network(topology, kind)
        patches, batch = check_patches(patches)
        feet = np.asarray(feet, dtype=np.float32)
        if feet.shape != batch + (6, 3):
            raise _error("feet", f"array of shape {feet.shape}", f"expected {batch + (6, 3)} to match the patches")
        n = int(np.prod(batch, dtype=np.int64))
        extra = feet.reshape(n, 18)
        d = check_direction(kind, direction, batch)
        if d is not None:
            extra = np.column_stack([extra, d.reshape(n).astype(np.float32)])
        out = np.empty(n, dtype=np.float64)
        x = torch.from_numpy(np.ascontiguousarray(patches.reshape(n, P.PATCH_SIZE, P.PATCH_SIZE)))
        e = torch.from_numpy(np.ascontiguousarray(extra))
        with torch.inference_mode():
            for start in range(0, n, INFERENCE_BATCH):
                stop = start + INFERENCE_BATCH
                out[start:stop] = net.probability(x[start:stop].to(self.device),
                                                  e[start:stop].to(self.device)).cpu().numpy()
        return out.reshape(batch)

    def turn_success(self, patches, feet, topology: str) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) success of turning from the same queries: the same as ``success``
        with d = 0 and d = 1, but the patch head runs once for both directions."""
        self.success(np.asarray(patches)[:0], np.asarray(feet)[:0], "turn", topology, direction=0)  # checks shapes
        left_right, _, _ = self.success_all(patches, {topology: feet}, "turn")[topology]
        return left_right[0], left_right[1]

    def success_all(self, patches, feet: dict, kind: str) -> dict:
        """Every listed topology's network of one kind on the same patches, each with its own
        feet: topology -> (success, plan, spread), success as ``success`` gives it (to float32
        rounding), plan the chance that the BLC plans the move (None for a network with the
        paper's single output), spread the standard deviation of an ensemble's members'
        success (networks.CapabilityEnsemble; None for a single network); for turns each is
        (2, ...): left (d = 0), right (d = 1).

        Every network (every ensemble member of every topology) runs at once, as one stack
        (:class:`_StackedMembers`): the first convolutions as one convolution of their stacked
        kernels over the raw patches (the input is read once), the second as one grouped
        convolution, the dense layers as batched matrix products. Each network standardises its
        input with its own scalars, z = (h - mean) / scale, zero-padded; the convolution is
        linear, so conv(pad0(z)) = conv_{W / scale}(pad0(h)) - (mean / scale) conv_W(pad0(1)) +
        b, where the last map (the kernel's sum over the patch's interior) is computed once per
        network.

        Args:
            patches: (..., 20, 20) height patches [m], the same for every topology.
            feet: topology -> (..., 6, 3) start feet in the heading frame [m].
            kind: orthogonal, diagonal or turn.
        """
        import torch

        from qz_drake.capability.networks import _max_pool_2x2

        P.check_kind(kind)
        topologies = list(feet)
        nets = [self.network(t, kind) for t in topologies]
        # Every member of every topology's network, with the topology it answers for.
        members = [(i, m) for i, net in enumerate(nets) for m in getattr(net, "members", [net])]
        patches, batch = check_patches(patches)
        n = int(np.prod(batch, dtype=np.int64))
        extras = []
        for t in topologies:
            f = np.asarray(feet[t], dtype=np.float32)
            if f.shape != batch + (6, 3):
                raise _error(f"feet[{t}]", f"array of shape {f.shape}",
                             f"expected {batch + (6, 3)} to match the patches")
            extras.append(torch.from_numpy(np.ascontiguousarray(f.reshape(n, 18))))
        flat = np.ascontiguousarray(patches.reshape(n, P.PATCH_SIZE * P.PATCH_SIZE))
        # The convolutions run once per distinct patch (a map's flat ground repeats one patch
        # from cell to cell); the dense layers once per query, with its own feet.
        first, inverse = distinct_rows(flat)
        order = np.argsort(inverse, kind="stable")  # queries grouped by their distinct patch
        bounds = np.searchsorted(inverse[order], np.arange(len(first) + 1))
        device = self.device
        x = torch.from_numpy(flat[first].reshape(len(first), 1, P.PATCH_SIZE, P.PATCH_SIZE)).to(device)
        by_topology = (torch.stack(extras, dim=1) if extras else torch.zeros(n, 0, 18)).to(device)  # (n, T, 18)
        directions = (P.TURN_LEFT, P.TURN_RIGHT) if kind == "turn" else (None,)
        out = np.empty((len(members), len(directions), n))
        plan = np.full((len(members), len(directions), n), np.nan)
        owners = torch.as_tensor([i for i, _ in members], device=device)
        nets_m = [m for _, m in members]
        with torch.inference_mode():
            stacked = _StackedMembers(nets_m)
            chunk = max(16, INFERENCE_BATCH_ALL * 6 // len(members))
            for start in range(0, len(first), chunk):
                stop = min(start + chunk, len(first))
                features = stacked.features(x[start:stop])
                queries = order[bounds[start]:bounds[stop]]
                for a in range(0, len(queries), chunk):
                    q = queries[a:a + chunk]
                    qt = torch.from_numpy(q).to(device)
                    f = features[torch.from_numpy(inverse[q] - start).to(device)]
                    extra = by_topology[qt][:, owners]  # (B, M, 18)
                    for k, d in enumerate(directions):
                        e = extra
                        if d is not None:
                            e = torch.cat([extra, torch.full(extra.shape[:2] + (1,), float(d), device=device)], dim=2)
                        success, planned = stacked.outputs(f, e)
                        out[:, k, q] = success.T.cpu().numpy()
                        if planned is not None:
                            plan[:, k, q] = planned.T.cpu().numpy()
        shape = (len(directions),) + batch if kind == "turn" else batch
        result = {}
        for i, t in enumerate(topologies):
            rows = [j for j, (owner, _) in enumerate(members) if owner == i]
            success = out[rows].mean(axis=0).reshape(shape)
            planned = plan[rows].mean(axis=0).reshape(shape) if nets[i].factored else None
            spread = out[rows].std(axis=0).reshape(shape) if len(rows) > 1 else None
            result[t] = (success, planned, spread)
        return result
