"""The capability CNN of paper 000 (section II-E.1, Fig. 4) as a torch module.

Two heads: the 20 x 20 height patch goes through two convolution layers of four 5 x 5 kernels
with zero padding, each followed by 2 x 2 max pooling and a ReLU, then a dense layer; the
second head is the start feet in the heading frame (18 numbers) and, for the turn network,
the direction d. The two are concatenated and go through two dense layers; a sigmoid gives
the success probability.

A second output (``NetworkConfig.factored``, the default): the last layer has two logits, the
paper's success and that the BLC finds a plan for the move (p_plan). A failure the BLC could
not plan leaves the robot standing where it was and the planner can go round it; the rest
(the BLC planned, the walk failed) is a fall, a leg in the terrain, a slip. Which of the two a
failure is depends on the terrain (on obstacles 58 % of the trials' failures are the BLC's, on
slopes all of them), and the planner's MDP needs it per state
(qz_drake.planning.capability_mdp). Both outputs are trained on every trial, on its
``success`` and ``blc_success`` labels. (Tried first: success as p_plan * p_walk, the walk
output trained on the planned trials only; on the same 12 214 trials and split it scored a
mean test AUC of 0.923 against the single output's 0.943: the walk output sees fewer trials.)

Three outcomes (``NetworkConfig.outcomes``, the default since issue 37): the last layer has
three logits and a softmax gives the probabilities of what a mission ends in: it walked; the
BLC found no plan (the robot stands where it was); it was executed and failed (a fall, a leg on
the terrain, a slip, a missed target). The three sum to one by construction, so "executed and
failed" is the model's own output rather than the difference of two independently fitted
ones (a 2 % event read off as p_plan - p_success). ``success_of`` is P(walked) and ``plan_of``
1 - P(no plan), so the planner reads a three-outcome network as it reads a factored one.

Inputs are standardised inside the module (fixed buffers set from the training set and saved
with the weights), so that callers pass heights and feet in metres as qz_drake.capability.patches
makes them and a saved network is self-contained.

Importing this module imports torch; qz_drake.capability.model imports it only when a model
is loaded or trained.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn

from qz_drake.capability.patches import PATCH_SIZE, check_kind

# Start feet in the heading frame, (6, 3) flattened.
FEET_INPUTS = 18


@dataclasses.dataclass
class NetworkConfig:
    """Layer sizes of one capability network; the paper fixes the convolutions only."""

    # Kernels per convolution layer (paper 000: four).
    conv_channels: int = 4
    # Side of the square convolution kernels (paper 000: 5 x 5); odd, zero padding keeps the size.
    kernel_size: int = 5
    # Width of the dense layer after the flattened convolution features (not given by the paper).
    patch_features: int = 32
    # Width of the first of the two dense layers after the concatenation (not given by the paper).
    hidden: int = 64
    # Two outputs, success and p_plan (see the module docstring); False: the paper's one.
    # Ignored when ``outcomes`` is set.
    factored: bool = True
    # Three outcomes as one softmax: walked, no plan, executed and failed (module docstring).
    outcomes: bool = True

    @property
    def outputs(self) -> int:
        return 3 if self.outcomes else 2 if self.factored else 1


def extra_inputs(kind: str) -> int:
    """Width of the second head: the feet, plus d for the turn network."""
    return FEET_INPUTS + (1 if check_kind(kind) == "turn" else 0)


def _max_pool_2x2(x: torch.Tensor) -> torch.Tensor:
    # The same as nn.MaxPool2d(2) on an even-sized map, written as the maximum of four strided
    # views: four times faster on the CPU for four channels, where pooling dominated inference.
    return torch.maximum(torch.maximum(x[:, :, 0::2, 0::2], x[:, :, 0::2, 1::2]),
                         torch.maximum(x[:, :, 1::2, 0::2], x[:, :, 1::2, 1::2]))


class CapabilityNet(nn.Module):
    """O(M_O, p), D(M_D, p) or S(M_S, d) of paper 000 Fig. 4: success probability of one action.

    ``forward(patch, extra)`` returns logits for patches (B, 20, 20) [m] and the second head
    (B, 18) or (B, 19) [m, and d in {0, 1}]: (B,) success logits, (B, 2) success and plan
    logits when factored, or (B, 3) logits of walked / no plan / executed and failed with
    ``outcomes``; :meth:`probability` gives the success probability (B,) in every case,
    :meth:`plan_probability` the chance that the BLC plans the move and
    :meth:`failure_probability` the chance it is executed and fails.
    """

    def __init__(self, kind: str, config: NetworkConfig | None = None):
        super().__init__()
        config = config or NetworkConfig()
        self.kind = check_kind(kind)
        self.config = config
        c, k = int(config.conv_channels), int(config.kernel_size)
        self.conv1 = nn.Conv2d(1, c, k, padding=k // 2)
        self.conv2 = nn.Conv2d(c, c, k, padding=k // 2)
        pooled = PATCH_SIZE // 4
        self.patch_dense = nn.Linear(c * pooled * pooled, int(config.patch_features))
        n_extra = extra_inputs(kind)
        self.dense1 = nn.Linear(int(config.patch_features) + n_extra, int(config.hidden))
        # Whether the network tells a plan not found from a failed execution (two or three
        # outputs), and whether as three outcomes.
        self.outcomes = bool(config.outcomes)
        self.factored = self.outcomes or bool(config.factored)
        self.dense2 = nn.Linear(int(config.hidden), config.outputs)
        # Input standardisation, set by set_input_scaling from the training set.
        self.register_buffer("patch_mean", torch.zeros(()))
        self.register_buffer("patch_scale", torch.ones(()))
        self.register_buffer("extra_mean", torch.zeros(n_extra))
        self.register_buffer("extra_scale", torch.ones(n_extra))

    def set_input_scaling(self, patches: torch.Tensor, extra: torch.Tensor) -> None:
        """Standardises inputs with the training set's statistics (one scalar for the heights,
        so that the patch keeps its shape; one per entry of the second head)."""
        with torch.no_grad():
            self.patch_mean.copy_(patches.mean())
            self.patch_scale.copy_(patches.std().clamp_min(1e-3))
            self.extra_mean.copy_(extra.mean(dim=0))
            # d is 0 or 1 and some feet coordinates barely vary: keep a floor on the scale.
            self.extra_scale.copy_(extra.std(dim=0).nan_to_num(1.0).clamp_min(1e-2))

    def encode_patch(self, patch: torch.Tensor) -> torch.Tensor:
        """The patch head: (B, 20, 20) heights [m] -> (B, patch_features)."""
        x = ((patch - self.patch_mean) / self.patch_scale).unsqueeze(1)
        x = torch.relu(_max_pool_2x2(self.conv1(x)))
        x = torch.relu(_max_pool_2x2(self.conv2(x)))
        return torch.relu(self.patch_dense(x.flatten(1)))

    def head(self, features: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        """The two dense layers after the concatenation; logits (B,), (B, 2) when factored or
        (B, 3) with three outcomes."""
        e = (extra - self.extra_mean) / self.extra_scale
        x = torch.relu(self.dense1(torch.cat([features, e], dim=1)))
        out = self.dense2(x)
        return out if self.factored else out.squeeze(1)

    def forward(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        return self.head(self.encode_patch(patch), extra)

    @staticmethod
    def outcomes_of(logits: torch.Tensor) -> torch.Tensor | None:
        """(B, 3) probabilities of walked, no plan, executed and failed of three-outcome logits;
        None for the other kinds."""
        return torch.softmax(logits, dim=1) if logits.dim() == 2 and logits.shape[1] == 3 else None

    @staticmethod
    def success_of(logits: torch.Tensor) -> torch.Tensor:
        """Success probability (B,) of the logits ``forward`` or ``head`` returned."""
        if logits.dim() == 2 and logits.shape[1] == 3:
            return torch.softmax(logits, dim=1)[:, 0]
        return torch.sigmoid(logits[:, 0] if logits.dim() == 2 else logits)

    @staticmethod
    def plan_of(logits: torch.Tensor) -> torch.Tensor | None:
        """P(the BLC plans the move) (B,) of factored or three-outcome logits; None for the
        paper's one output."""
        if logits.dim() == 2 and logits.shape[1] == 3:
            return 1.0 - torch.softmax(logits, dim=1)[:, 1]
        return torch.sigmoid(logits[:, 1]) if logits.dim() == 2 else None

    @staticmethod
    def failure_of(logits: torch.Tensor) -> torch.Tensor | None:
        """P(executed and failed) (B,): a three-outcome network's own output, a factored one's
        p_plan - p_success (at least 0); None for the paper's one output."""
        if logits.dim() == 2 and logits.shape[1] == 3:
            return torch.softmax(logits, dim=1)[:, 2]
        if logits.dim() == 2:
            return (torch.sigmoid(logits[:, 1]) - torch.sigmoid(logits[:, 0])).clamp_min(0.0)
        return None

    def probability(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        return self.success_of(self.forward(patch, extra))

    def plan_probability(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor | None:
        return self.plan_of(self.forward(patch, extra))

    def failure_probability(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor | None:
        return self.failure_of(self.forward(patch, extra))

    def outcome_probabilities(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor | None:
        return self.outcomes_of(self.forward(patch, extra))


class CapabilityEnsemble(nn.Module):
    """Several CapabilityNets of one (topology, kind) trained alike from other seeds (issue 37):
    a deep ensemble. Its probabilities are the members' means; where the members disagree the
    data did not pin the answer down, and the planner reads their spread (:meth:`spread`,
    the standard deviation of the members' success) as a reason to doubt the mean
    (qz_drake.planning.capability_mdp, ``pessimism``).

    It answers what a CapabilityNet answers (``probability``, ``plan_probability``,
    ``failure_probability``; ``kind``, ``config``, ``factored``, ``outcomes``), and
    ``members`` lists the nets (CapabilityModel.success_all evaluates them one by one).
    """

    def __init__(self, members: list[CapabilityNet]):
        super().__init__()
        if not members:
            raise ValueError("an ensemble needs at least one member")
        first = members[0]
        if any(m.kind != first.kind or m.config != first.config for m in members):
            raise ValueError("ensemble members must share their kind and network config")
        self.members = nn.ModuleList(members)
        self.kind, self.config = first.kind, first.config
        self.factored, self.outcomes = first.factored, first.outcomes

    def _mean(self, fn, patch, extra):
        outs = [fn(m(patch, extra)) for m in self.members]
        return None if outs[0] is None else torch.stack(outs).mean(dim=0)

    def probability(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        return self._mean(CapabilityNet.success_of, patch, extra)

    def plan_probability(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor | None:
        return self._mean(CapabilityNet.plan_of, patch, extra)

    def failure_probability(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor | None:
        return self._mean(CapabilityNet.failure_of, patch, extra)

    def outcome_probabilities(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor | None:
        """(B, 3) mean of the members' three outcomes; None for other kinds of members."""
        return self._mean(CapabilityNet.outcomes_of, patch, extra)

    def spread(self, patch: torch.Tensor, extra: torch.Tensor) -> torch.Tensor:
        """(B,) standard deviation of the members' success probabilities (0 for one member)."""
        p = torch.stack([CapabilityNet.success_of(m(patch, extra)) for m in self.members])
        return p.std(dim=0, unbiased=False)
