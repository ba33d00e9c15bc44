"""The capability MDP of paper 000 section II-E.2: grid-world planning with learned success
probabilities, solved by value iteration (Eq. 9-10).

States: (cell, heading, topology) of a grid of 1 m cells over the heightmap, with 8 headings
(yaw k * 45 deg) and the robot's current topology, plus two absorbing states, goal and
failure. Actions: (topology, motion) with motion forward (one cell along the heading: the
orthogonal network for even k, the diagonal one for odd k), turn left or turn right (45 deg
in place, the turn network with d = 0 / 1): 3 x 6 = 18 actions. The success probability of an
action is the CapabilityModel's for the action's topology from the current cell and heading,
the robot standing on that topology's nominal footholds; all of them come from one batched
evaluation of the map (qz_drake.capability.model.predict_map). With probability p the robot
reaches the next (cell, heading) in the new topology (the goal state when that cell is the
goal's). A failure is one of two things, and the trials tell them apart: the BLC found no plan
(the robot stands where it was, and the TLC goes round: qz_drake.planning.capability_planner)
or the walk failed (a fall, a leg in the terrain, a slip: the end). With q the probability
that the BLC finds no plan, the robot stays in its state with probability q at
``plan_failure_cost``, and falls into the absorbing failure state with probability (1 - p) - q.
q is the two-output model's own, per state and action (1 - p_plan: networks.NetworkConfig.
factored); for a model with the paper's single output, share * (1 - p) with the network's
measured share of planning failures (``plan_failure_share``); the config can fix the share.
A forward move off the grid and a topology change where none can be made fail outright. The
BLC is deterministic: what it could not plan from a state it will not plan there the next time,
and the TLC forbids the action there (``forbid_action``). So after a planning failure the
robot chooses again *among the other actions*: :func:`solve_capability_mdp` iterates
Q(s, a) = r(s, a) + gamma (sum_s' P(s, a, s') V(s') + q(s, a) max_{b != a} Q(s, b)), the
self-loop's value being the best other action's (a contraction in Q of modulus gamma, like
Eq. 9). With a plain self-loop the MDP would count on
retrying: an action of p = 0.4 would look like 0.4 / (1 - q) = 0.75, and the route would seek
such actions.

Why not every failure terminal (the first reading of the paper's "negative reward"): about 80 %
of the trials' failures are the BLC's, after which the robot stands unharmed. With all of them
terminal, a route of n moves of p = 0.95 keeps 0.95^n of the goal's reward, and beyond about
1 / (1 - gamma * p) = 17 moves every cell's value is the failure's: on a 100 m map the policy far
from the goal no longer points at it. The self-loop is a Markov approximation: a planning
failure repeats from the same state (the BLC is deterministic), and the planner forbids that
action there after one (``forbid_action``): the solver values the stay by the other actions.

Why the topology is in the state: the paper's Fig. 8 robot changes topology "to better adapt
to tough terrain", which is only worth it where it pays; a cost for *changing* topology needs
the current topology to be known, and in a Markov state that means in the state (a cost on
actions alone could only tax using a topology, not switching to it). The state count grows
six-fold (20 m x 20 m: 19 202 states), which sparse transitions absorb easily: each action
has two next states. The change itself is assumed to succeed; its risk is the following
action's, evaluated in the new topology.

Rewards (expected, per state and action): ``-action_cost`` for any action, ``-topology_change_cost``
when the action's topology differs from the state's, ``goal_reward`` on reaching the goal,
``failure_reward`` on failing, ``-plan_failure_cost`` on a planning failure; zero in the
absorbing states. The policy is Eq. 10's greedy
one; :func:`most_likely_path` follows it from a start, taking each action's successful outcome.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from qz_drake.capability import patches as P
from qz_drake.errors import bad_value
from qz_drake.planning.value_iteration import ValueIterationResult, value_iteration
from qz_drake.robot.topology import TOPOLOGY_NAMES

MOTIONS = ("forward", "turn_left", "turn_right")
# Most policy evaluations in one solve, then Eq. 9 alone (a contraction: it always converges).
# The runner-up's successor is valued one evaluation behind, so in principle the greedy policy
# could cycle; measured: 43 evaluations on the 100 m world, 11-16 on 20 m.
MAX_EVALUATIONS = 200
# Passes of each policy evaluation (_compile_kernels' greedy_values): the runner-up's successor is valued at
# the previous pass's values. Measured 2026-12-02 on the bench's 100 m map: 1 pass 51
# iterations (43 evaluations), 2 passes 32, 3-4 passes 29-32 at more time a pass; the same
# path. 2: the fastest (BENCHMARKS "plan").
GREEDY_PASSES = 2
# Cell step (dx, dy) of a forward move along heading k.
HEADING_STEPS = np.array([(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)])


def check_turn_edge_risk(value, field: str = "turn_edge_risk") -> float:
    """A turn's risk beside an edge (CapabilityMdpConfig.turn_edge_risk) as a float; anything but
    a number in [0, 1] is a QzError naming ``field``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:  # NaN too
        raise bad_value(field, value, "must be in [0, 1]")
    return float(value)


@dataclasses.dataclass
class CapabilityMdpConfig:
    """Rewards and solver settings of the capability MDP; each default with its reason."""

    # Reward on reaching the goal: large against the per-action cost, so that the goal is
    # worth a detour of tens of actions (the paper: "a large positive reward").
    goal_reward: float = 100.0
    # Reward on a failed action (the paper: "a negative reward"). As large as the goal's: an
    # action with success p then loses about (1 - p) * 200 against a safe one, so a 5 % risk
    # is worth avoiding at a detour of up to ~10 actions. A fall ends the mission either way.
    failure_reward: float = -100.0
    # Share of an action's failure probability that is the BLC finding no plan (the robot
    # stands where it was; the rest end the walk). None: the model's (a factored model's
    # P(no plan) per state and action; else each network's share measured on its training
    # trials, CapabilityModel.plan_failure_share; 0 where the model does not say, as a random
    # model); a number in [0, 1]: that share for every action (0: every failure ends the
    # walk). A constant share is a poor guess where it matters: 58 % of the obstacle trials'
    # failures are the BLC's against 77 % overall, and near a tall obstacle fewer.
    plan_failure_share: float | None = None
    # Share of the predicted planning failures counted as falls instead (0: the model's split
    # as it is; 1: every failure ends the walk, i.e. plan by the actions' success alone). In
    # the Fig. 9 experiment (BENCHMARKS "fig9") the walks on box fields ended as often as the
    # success product predicted (0.35 walked, 0.37 predicted on obstacles-medium), not as the
    # no-fall probability did (0.77): the failures the model took for harmless planning
    # failures were legs on boxes. A knob to tune on the tuning worlds, 0 by default. Tuned with
    # the three-outcome model (session 39, BENCHMARKS "fig9"): on the Fig. 9 tuning worlds 1
    # walked 126 of 192 paired walks against 0's 116 (11 only with 1, 1 only with 0), since the
    # BLC is deterministic and a move refused from a stance stays refused; the experiment walks
    # with the tuned 1. The default stays 0 for routes of hundreds of moves, where counting every
    # refusal as the end collapses the route's value (test_a_long_route_reaches_the_goal_...).
    plan_failure_risk: float = 0.0
    # Doubt where an ensemble's members disagree (issue 37): an action's success is planned
    # with as p - pessimism * spread, spread the standard deviation of the members' success
    # (CapabilityMap.forward_spread etc.; a map without spreads is taken as it is); the
    # probability taken from success goes to the failure state. A topology the networks are
    # unsure of is then chosen only where its gain exceeds that doubt. 0: the mean alone.
    pessimism: float = 1.0
    # Doubt about a topology change (issue 37): an action of another topology than nominal is
    # planned with nominal's (pessimistic) success of the same action plus only the part of its
    # advantage that exceeds pessimism * sqrt(s_t^2 + s_nominal^2), the ensemble's doubt about
    # the difference (members' errors taken as independent: more doubt than correlated ones);
    # a disadvantage counts in full. Without it each topology is doubted by its own spread
    # alone, and where nominal's spread is the larger the doubt itself favoured a switch (the
    # boosted model on medium validation worlds: switches for 0.01 a move; BENCHMARKS "fig9").
    # Needs a map with spreads and nominal among the topologies; else it does nothing. On by
    # default since session 38: on the validation worlds (seeds 500-503, medium and hard) the
    # walks that changed topology went from 17 of 24 to 1 and those that arrived from 15 to 17
    # (stairs-hard 2 -> 4 of 4; two interim boosted models of the same data, BENCHMARKS "fig9").
    topology_doubt: bool = True
    # Cost of a planning failure: the robot stood while the BLC searched, and the TLC replans;
    # about one action's time.
    plan_failure_cost: float = 1.0
    # Cost of every action (forward one cell or a 45 deg turn): prefers short routes with few
    # turns; small against the goal so that risk, not length, decides between corridors.
    action_cost: float = 1.0
    # Cost of a move or turn that passes within ``edge_reach`` of an edge (a map cell whose
    # height differs from a neighbour's by more than ``edge_height``: a step's riser, a box's
    # side), rising linearly from 0 at that distance to ``edge_cost`` on the edge. The BLC's
    # refusals are at edges for every planner (the median refused mission passes within 1-27 cm
    # of one), and A*'s cost map, which keeps its body off them, is refused half as often as
    # CapPlanner trusting the model alone (BENCHMARKS "capplanner, route data", session 49;
    # issue 54's "clearance from obstacles where the model is unsure"). 0: none, the paper's
    # TLC and every run before. [value units], [m], [m]
    edge_cost: float = 0.0
    edge_reach: float = 0.5
    edge_height: float = 0.05
    # Risk of a turn from a cell whose centre is within ``turn_edge_reach`` of an edge (as for
    # ``edge_cost``), rising linearly from 0 there to ``turn_edge_risk`` on the edge: that share
    # of the turn's success goes to the failure state. The model cannot see it: its trials
    # rarely turn the robot beside a box, and it predicts such turns fail 0.2 % of the time.
    # What the walks met (session 53, CapPlanner's and A*'s recorded missions of the 24 tuning
    # tasks, 21 runs; ``python benchmarks/turn_risk.py``): on box fields a turn in place from
    # within 0.2 m of an edge failed walking 41 times in 96 (0.2-0.3 m: 11 in 57; 0.3-0.4 m: 1
    # in 30; further: 6 in 290), a move that turned there 5 in 113, on stairs none of 6. 0: the
    # model's turns as they are (the paper's TLC, every run before). [probability], [m]
    turn_edge_risk: float = 0.0
    turn_edge_reach: float = 0.4
    # Extra cost of switching to another topology: a reconfiguration is a BLC mission of its
    # own on the robot (feet moved one by one), worth about two ordinary actions; the robot
    # changes topology only where the new one is clearly more capable.
    topology_change_cost: float = 2.0
    # Discount gamma: close to 1 so that a goal 60 actions away (across a 20 m map with
    # turns) still counts (0.99^60 = 0.55); the paper's reason for gamma is to rank cells by
    # their distance to the goal, which the discount and the action cost both do.
    discount: float = 0.99
    # Value accuracy of value iteration's stop (in reward units, against a goal of 100): the
    # greedy policy is then epsilon-optimal. 0.1 against 0.01 (2026-12-02, BENCHMARKS "plan"):
    # on the 100 m world 323 iterations instead of 507, the same path from corner to corner,
    # 16 of 470 450 states' actions different, values within 0.034; the success probabilities
    # themselves are uncertain by several hundredths.
    epsilon: float = 0.1
    # Most value iterations (the paper's 20 m map converged in about 60).
    max_iter: int = 5000
    # Between two iterations of Eq. 9, value the current greedy policy exactly (policy
    # iteration's evaluation step; modified policy iteration, Puterman 6.5). The same fixed
    # point and the same stop (the Bellman residual below epsilon's threshold), in far fewer
    # iterations: with Eq. 9 alone the values far from the goal settle at gamma per iteration.
    policy_evaluation: bool = True
    # Where the robot may change topology: only on level ground under its body (the least-
    # squares slope and the roughness of the terrain within 0.7 m of the cell centre). The
    # switch moves legs through fixed high joint-space poses; on a long_range walk a switch
    # on a 15 deg slope would have passed a foot 0.5 cm over the ground and was refused, which
    # ended the walk. The MDP gives a topology change elsewhere no success. [deg], [m]
    switch_max_slope_deg: float = 8.0
    switch_max_roughness: float = 0.03
    # ... and nothing within the legs' reach (SWITCH_REACH) standing out of the ground's plane
    # by more than this: each leg is lifted and swung to its new foothold. In a Fig. 9
    # obstacle world a switch beside a 0.13 m box (0.4 m from the cell centre; roughness over
    # the 0.7 m disc 0.01) passed a foot 3.4 cm into it and ended the walk. [m]
    switch_max_step: float = 0.03
    # Maps larger than the 20 m world: the discount's horizon 1 / (1 - gamma) (100 actions) and
    # the costs per action suit routes of up to ~100 actions, the 20 m world's. On a grid of
    # nx + ny cells above 40 both scale by k = (nx + ny) / 40: gamma -> 1 - (1 - gamma) / k and
    # the action, topology-change and planning-failure costs / k, so that a route across the
    # map still costs less than a fall and its goal still counts (the goal and failure rewards
    # stay). On 100 m x 100 m, corner to corner (2026-12-02, BENCHMARKS "plan"): unscaled, the
    # path stopped after 6 actions (every route looked worse than falling at once); scaled
    # (k = 5), it reaches the goal in 195 actions.
    scale_to_grid: bool = True
    # Grid cell. [m]
    cell_size: float = P.CELL_SIZE
    # Topologies the robot may use; empty: all six.
    topologies: list[str] = dataclasses.field(default_factory=list)
    # The stance the map assumes the robot stands in at every cell and heading: "nominal", the
    # topology's nominal footholds (the paper's map); "canonical", the stance every mission
    # ends in when the BLC's terminal_stance is "canonical" (trajopt/stance.py; issue 54).
    stance: str = "nominal"

    @property
    def needs_edge_clearance(self) -> bool:
        """Whether the MDP is built with the map's edge clearances (edge_clearances): for
        ``edge_cost`` or ``turn_edge_risk``."""
        return self.edge_cost > 0 or self.turn_edge_risk > 0

    def for_grid(self, nx: int, ny: int) -> "CapabilityMdpConfig":
        """The config a grid of nx x ny cells is planned with (``scale_to_grid``)."""
        k = (nx + ny) / 40.0
        if not self.scale_to_grid or k <= 1.0:
            return self
        return dataclasses.replace(self, discount=1.0 - (1.0 - self.discount) / k, action_cost=self.action_cost / k,
                                   edge_cost=self.edge_cost / k,
                                   topology_change_cost=self.topology_change_cost / k,
                                   plan_failure_cost=self.plan_failure_cost / k, scale_to_grid=False)

    def check(self) -> "CapabilityMdpConfig":
        for name in ("goal_reward", "action_cost", "topology_change_cost", "switch_max_slope_deg",
                     "switch_max_roughness", "switch_max_step", "plan_failure_cost", "pessimism", "edge_cost"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise bad_value(f"capability_mdp.{name}", getattr(self, name), "must be finite and >= 0")
        check_turn_edge_risk(self.turn_edge_risk, "capability_mdp.turn_edge_risk")
        for name in ("edge_reach", "edge_height", "turn_edge_reach"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise bad_value(f"capability_mdp.{name}", getattr(self, name), "must be finite and > 0 [m]")
        if not (np.isfinite(self.failure_reward) and self.failure_reward <= 0):
            raise bad_value("capability_mdp.failure_reward", self.failure_reward, "must be finite and <= 0")
        share = self.plan_failure_share
        if share is not None and not (isinstance(share, (int, float)) and not isinstance(share, bool)
                                      and 0.0 <= share <= 1.0):
            raise bad_value("capability_mdp.plan_failure_share", share, "must be a number in [0, 1] or null "
                            "(the model's measured shares)")
        if not (np.isfinite(self.plan_failure_risk) and 0.0 <= self.plan_failure_risk <= 1.0):
            raise bad_value("capability_mdp.plan_failure_risk", self.plan_failure_risk, "must be in [0, 1]")
        if not isinstance(self.topology_doubt, bool):
            raise bad_value("capability_mdp.topology_doubt", self.topology_doubt, "expected true or false")
        if not (0.0 < self.discount < 1.0):
            raise bad_value("capability_mdp.discount", self.discount, "must be in (0, 1)")
        for t in self.topologies:
            if t not in TOPOLOGY_NAMES:
                raise bad_value("capability_mdp.topologies", t, f"expected some of {', '.join(TOPOLOGY_NAMES)}")
        from qz_drake.capability.patches import check_stance

        check_stance(self.stance, "capability_mdp.stance")
        return self


@dataclasses.dataclass
class CapabilityMdp:
    """The MDP's arrays and its state / action numbering.

    State s = ((t * 8 + k) * ny + iy) * nx + ix for topology index t, heading k, cell (ix, iy);
    then ``goal_state`` and ``failure_state``. Action a = t * 3 + m, m indexing MOTIONS.
    """

    # (S, A) expected immediate rewards.
    R: np.ndarray
    # (A, S) success probability of each action from each state (0 in the absorbing states).
    success: np.ndarray
    # (A, S) the state reached on success.
    next_state: np.ndarray
    xs: np.ndarray
    ys: np.ndarray
    topologies: tuple[str, ...]
    # Goal cell (ix, iy).
    goal_cell: tuple[int, int]
    config: CapabilityMdpConfig
    # (T, 3) the share of planning failures used per topology and kind (orthogonal, diagonal,
    # turn); (A, S) the probability that an action leaves the robot standing where it was.
    plan_failure_share: np.ndarray | None = None
    stand: np.ndarray | None = None
    # Where the planning failures' probabilities came from: "model, per state" (a factored
    # model), "model cards' shares" (plan_failure_share above) or "config".
    plan_failure_source: str = ""
    # (ny, nx) the share of a turn's success lost near an edge (CapabilityMdpConfig.turn_edge_risk);
    # None: none.
    turn_risk: np.ndarray | None = None

    @property
    def P(self) -> list:
        """The transition matrices, A sparse (S, S) CSR, in pymdptoolbox's convention, built
        from the arrays each time (the solver reads the arrays; forbid_action writes them): with
        probability p the next state, q the same state (the planning failure's stay), the rest
        the failure state; an absorbing state stays."""
        import scipy.sparse as sp

        A, S = self.success.shape
        grid, failure = self.goal_state, self.failure_state
        rows = np.arange(S)
        absorbing = rows >= grid
        stand = np.zeros((A, S)) if self.stand is None else self.stand
        matrices = []
        for a in range(A):
            p, q = self.success[a], stand[a]
            stays = np.flatnonzero(q > 0)
            data = np.concatenate([np.where(absorbing, 1.0, p), (1.0 - p - q)[~absorbing], q[stays]])
            cols = np.concatenate([np.where(absorbing, rows, self.next_state[a]), np.full(grid, failure), stays])
            matrices.append(sp.csr_matrix((data, (np.concatenate([rows, rows[~absorbing], stays]), cols)),
                                          shape=(S, S)))
        return matrices

    @property
    def grid_shape(self) -> tuple[int, int, int, int]:
        """(T, 8, ny, nx)."""
        return (len(self.topologies), 8, len(self.ys), len(self.xs))

    @property
    def goal_state(self) -> int:
        return int(np.prod(self.grid_shape))

    @property
    def failure_state(self) -> int:
        return self.goal_state + 1

    def state(self, ix: int, iy: int, heading: int, topology: str) -> int:
        return int(np.ravel_multi_index((self.topologies.index(topology), int(heading) % 8, iy, ix), self.grid_shape))

    def unravel(self, s: int) -> tuple[int, int, int, str]:
        """(ix, iy, heading, topology) of a grid state."""
        t, k, iy, ix = np.unravel_index(int(s), self.grid_shape)
        return int(ix), int(iy), int(k), self.topologies[t]

    def action(self, a: int) -> tuple[str, str]:
        """(topology, motion) of action a."""
        return self.topologies[a // 3], MOTIONS[a % 3]

    def cell_of(self, x: float, y: float, field: str = "position", *, margin: float = 0.0) -> tuple[int, int]:
        """(ix, iy) of the grid cell containing world (x, y); a point up to ``margin`` beyond
        the grid's outer cells counts as in them (the grid holds whole cells only, so a strip
        of the map along its edges may lie outside it); an error further off."""
        half = 0.5 * self.config.cell_size
        fx = (x - (self.xs[0] - half)) / self.config.cell_size
        fy = (y - (self.ys[0] - half)) / self.config.cell_size
        slack = margin / self.config.cell_size
        if not (-slack <= fx < len(self.xs) + slack and -slack <= fy < len(self.ys) + slack):
            raise bad_value(field, [float(x), float(y)], f"off the planning grid x {self.xs[0] - half:.2f}.."
                            f"{self.xs[-1] + half:.2f}, y {self.ys[0] - half:.2f}..{self.ys[-1] + half:.2f} m")
        return (int(np.clip(np.floor(fx), 0, len(self.xs) - 1)), int(np.clip(np.floor(fy), 0, len(self.ys) - 1)))


# How far the robot's feet reach from its body centre: the farthest nominal foothold (split_up,
# 0.83 m) and the foot. A robot in a cell closer to the heightmap's edge stands with feet off the
# terrain: two CapPlanner walks on simple validation worlds walked along the row of cells 0.5 m
# from the world's edge and fell off it (issue 38). [m]
MAP_EDGE_REACH = 0.9
# The ground a topology switch needs level: Qingzhui's trunk half-diagonal. [m]
SWITCH_RADIUS = 0.7
# The ground its legs sweep: the farthest nominal foothold (split_up, 0.83 m) and the foot's
# kinematic box. [m]
SWITCH_REACH = 0.95
SWITCH_SPACING = 0.1  # [m]


def _disc(radius: float):
    step = np.arange(-radius, radius + 1e-9, SWITCH_SPACING)
    dx, dy = np.meshgrid(step, step)
    inside = dx ** 2 + dy ** 2 <= radius ** 2
    return dx[inside], dy[inside]


def switchable_cells(heightmap, xs, ys, config: CapabilityMdpConfig | None = None) -> np.ndarray:
    """(ny, nx) True where the robot may change topology: the terrain around the cell centre
    (xs, ys) is level and smooth enough (``switch_max_slope_deg``, ``switch_max_roughness``)
    under the body, and flat within the legs' reach (``switch_max_step``)."""
    config = config or CapabilityMdpConfig()
    # The terrain on discs around each cell centre, sampled every SWITCH_SPACING (paper 003's
    # body features, Eq. 7-8, at the cells only: on a 100 m map the whole-map features took
    # 2.9 s, these 0.14 s).
    X, Y = np.meshgrid(np.asarray(xs, dtype=float), np.asarray(ys, dtype=float))

    def plane(radius):
        dx, dy = _disc(radius)
        z = np.asarray(heightmap.height(X[..., None] + dx, Y[..., None] + dy), dtype=float)
        # Least-squares plane over a symmetric disc: slopes sum(d z) / sum(d^2) along x and y.
        a = (z * dx).sum(axis=-1) / (dx ** 2).sum()
        b = (z * dy).sum(axis=-1) / (dy ** 2).sum()
        residual = z - z.mean(axis=-1, keepdims=True) - a[..., None] * dx - b[..., None] * dy
        return z, a, b, residual

    z, a, b, _ = plane(SWITCH_RADIUS)
    slope = np.arctan(np.hypot(a, b))
    roughness = z.std(axis=-1)
    step = np.abs(plane(SWITCH_REACH)[3]).max(axis=-1)
    return ((slope <= np.radians(config.switch_max_slope_deg)) & (roughness <= config.switch_max_roughness)
            & (step <= config.switch_max_step))


def edge_clearances(heightmap, xs, ys, config: CapabilityMdpConfig | None = None) -> np.ndarray:
    """(K + 1, ny, nx): how far [m] each forward move from the cell centres (xs, ys) along
    heading k < K passes from the nearest edge (:func:`edge_distances`), at most ``edge_reach``
    (or ``turn_edge_reach``, the larger); index K, a turn's: the distance at the cell centre."""
    config = config or CapabilityMdpConfig()
    X, Y = np.meshgrid(np.asarray(xs, dtype=float), np.asarray(ys, dtype=float))
    reach = float(max(config.edge_reach, config.turn_edge_reach))
    out = np.full((len(HEADING_STEPS) + 1, *X.shape), reach)
    distance = edge_distances(heightmap, config.edge_height)
    if distance is None:
        return out
    res = heightmap.resolution
    for k, (sx, sy) in enumerate(HEADING_STEPS):
        n = int(np.ceil(np.hypot(sx, sy) * config.cell_size / res)) + 1
        t = np.linspace(0.0, 1.0, n)
        ix, iy = heightmap.index(X[..., None] + t * sx * config.cell_size, Y[..., None] + t * sy * config.cell_size)
        out[k] = np.minimum(distance[iy, ix].min(axis=-1), reach)
    ix, iy = heightmap.index(X, Y)
    out[-1] = np.minimum(distance[iy, ix], reach)
    return out


def edge_distances(heightmap, edge_height: float) -> np.ndarray | None:
    """(rows, cols) of the heightmap: each map cell's distance [m] from the nearest edge (a map
    cell whose height differs from a neighbour's by more than ``edge_height``); None where the
    map has no edge."""
    from scipy.ndimage import distance_transform_edt

    h = np.asarray(heightmap.heights, dtype=float)
    jump = np.zeros(h.shape, dtype=bool)
    dy, dx = np.abs(np.diff(h, axis=0)) > edge_height, np.abs(np.diff(h, axis=1)) > edge_height
    jump[:-1] |= dy
    jump[1:] |= dy
    jump[:, :-1] |= dx
    jump[:, 1:] |= dx
    if not jump.any():
        return None
    return distance_transform_edt(~jump) * heightmap.resolution


def cells_on_map(heightmap, xs, ys) -> np.ndarray:
    """(ny, nx) True where a robot at the cell centre (xs, ys) has all its feet on the heightmap:
    the centre at least MAP_EDGE_REACH inside the map's edges."""
    xmin, xmax, ymin, ymax = heightmap.bounds
    X, Y = np.meshgrid(np.asarray(xs, dtype=float), np.asarray(ys, dtype=float))
    return ((X - MAP_EDGE_REACH >= xmin) & (X + MAP_EDGE_REACH <= xmax)
            & (Y - MAP_EDGE_REACH >= ymin) & (Y + MAP_EDGE_REACH <= ymax))


def action_reward(config: CapabilityMdpConfig, p, q, to_goal, switch):
    """An action's expected immediate reward (arrays or numbers): its cost and a topology
    change's, the goal's reward where it succeeds into the goal (probability p), the failure's
    where it neither succeeds nor leaves the robot standing (1 - p - q), a stand's cost (q)."""
    return (-config.action_cost - config.topology_change_cost * switch
            + p * config.goal_reward * to_goal + (1.0 - p - q) * config.failure_reward
            - q * config.plan_failure_cost)


def build_capability_mdp(capability_map, goal_xy, config: CapabilityMdpConfig | None = None,
                         switchable: np.ndarray | None = None, on_map: np.ndarray | None = None,
                         edge_clearance: np.ndarray | None = None) -> CapabilityMdp:
    """The MDP of a CapabilityMap (qz_drake.capability.model.predict_map) and a goal position;
    ``switchable`` (ny, nx): where a topology change can succeed (:func:`switchable_cells`;
    None: everywhere); ``on_map`` (ny, nx): the cells a robot may stand in (:func:`cells_on_map`;
    None: all): a move into another fails, as a move off the grid does (the goal's cell is
    always allowed); ``edge_clearance`` (K + 1, ny, nx): each move's and turn's distance from an
    edge (:func:`edge_clearances`), which ``edge_cost`` charges for (needed when it is > 0)."""
    T, K, ny, nx = capability_map.forward.shape
    config = (config or CapabilityMdpConfig()).check().for_grid(nx, ny)
    topologies = tuple(capability_map.topologies)
    mdp = CapabilityMdp(R=np.empty(0), success=np.empty(0), next_state=np.empty(0),
                        xs=np.asarray(capability_map.xs), ys=np.asarray(capability_map.ys), topologies=topologies,
                        goal_cell=(0, 0), config=config)
    # A goal in the map's edge strip outside the whole cells belongs to the nearest cell.
    mdp.goal_cell = mdp.cell_of(*goal_xy, field="goal", margin=config.cell_size)
    grid = T * K * ny * nx
    S, A = grid + 2, 3 * T
    goal, failure = grid, grid + 1
    t0, k, iy, ix = np.unravel_index(np.arange(grid), (T, K, ny, nx))
    at_goal = (ix == mdp.goal_cell[0]) & (iy == mdp.goal_cell[1])
    allowed = np.ones((ny, nx), dtype=bool) if on_map is None else np.array(on_map, dtype=bool)
    if allowed.shape != (ny, nx):
        raise bad_value("on_map", f"array of shape {allowed.shape}", f"expected ({ny}, {nx}), the map's cells")
    allowed[mdp.goal_cell[1], mdp.goal_cell[0]] = True
    success = np.zeros((A, S))
    stand = np.zeros((A, S))
    next_state = np.tile(np.arange(S), (A, 1))
    R = np.zeros((S, A))
    mdp.plan_failure_share = _plan_failure_shares(capability_map, config, T)
    mdp.plan_failure_source = ("config" if config.plan_failure_share is not None else
                               "model, per state" if getattr(capability_map, "forward_plan", None) is not None
                               else "model cards' shares")
    reference = _reference_motions(capability_map, config, topologies, k, iy, ix, allowed)
    near_edge = turn_kept = None
    if config.needs_edge_clearance:
        if edge_clearance is None:
            raise bad_value("edge_clearance", None, "needed with capability_mdp.edge_cost or turn_edge_risk > 0 "
                                                    "(edge_clearances of the map)")
        clearance = np.asarray(edge_clearance, dtype=float)
        if clearance.shape != (K + 1, ny, nx):
            raise bad_value("edge_clearance", f"array of shape {clearance.shape}", f"expected ({K + 1}, {ny}, {nx})")
        if config.edge_cost > 0:
            closeness = np.clip(1.0 - clearance / config.edge_reach, 0.0, 1.0)
            near_edge = (closeness[k, iy, ix], closeness[K, iy, ix], closeness[K, iy, ix])
        if config.turn_edge_risk > 0:
            mdp.turn_risk = config.turn_edge_risk * np.clip(1.0 - clearance[K] / config.turn_edge_reach, 0.0, 1.0)
            turn_kept = 1.0 - mdp.turn_risk[iy, ix]
    for t in range(T):
        # Grid state of the same cell and heading in topology t (the action's).
        same = np.ravel_multi_index((np.full(grid, t), k, iy, ix), (T, K, ny, nx))
        on_grid, fx, fy = _forward_cell(k, iy, ix, allowed)
        forward_next = np.where(on_grid, np.ravel_multi_index((np.full(grid, t), k, np.clip(fy, 0, ny - 1),
                                                               np.clip(fx, 0, nx - 1)), (T, K, ny, nx)), failure)
        forward_goal = on_grid & (fx == mdp.goal_cell[0]) & (fy == mdp.goal_cell[1])
        motions = (
            (capability_map.forward[t, k, iy, ix] * on_grid, np.where(forward_goal, goal, forward_next)),
            (capability_map.turn_left[t, k, iy, ix], same + (((k + 1) % K) - k) * ny * nx),
            (capability_map.turn_right[t, k, iy, ix], same + (((k - 1) % K) - k) * ny * nx),
        )
        share = mdp.plan_failure_share[t]
        shares = (np.where(k % 2 == 0, share[0], share[1]), share[2], share[2])
        planned = _plan_probabilities(capability_map, config, t, k, iy, ix)
        spreads = _spreads(capability_map, t, k, iy, ix)
        for m, (p, nxt) in enumerate(motions):
            a = 3 * t + m
            if spreads is not None and config.pessimism > 0:
                doubted = np.asarray(p, dtype=float) - config.pessimism * spreads[m]
                if reference is not None and topologies[t] != REFERENCE_TOPOLOGY:
                    p_ref, s_ref = reference[m]
                    base = p_ref - config.pessimism * s_ref
                    gain = np.asarray(p, dtype=float) - p_ref
                    doubt = config.pessimism * np.sqrt(spreads[m] ** 2 + s_ref ** 2)
                    doubted = np.where(gain > 0.0, base + np.maximum(gain - doubt, 0.0), np.minimum(doubted, base))
                p = doubted
            p = np.clip(np.asarray(p, dtype=float), 0.0, 1.0)
            if turn_kept is not None and m > 0:  # a turn beside an edge: the walks' risk the model misses
                p = p * turn_kept
            # What the BLC could not plan leaves the robot standing; a forward move off the grid
            # and a refused topology change are not the BLC's and fail outright.
            if planned is not None:  # the factored model's own P(no plan) of this state and action
                q = np.clip(1.0 - planned[m], 0.0, 1.0 - p)
            else:
                q = (1.0 - p) * shares[m]
            q = q * (on_grid if m == 0 else 1.0) * (1.0 - config.plan_failure_risk)
            if switchable is not None:  # a topology change where the robot cannot make one fails
                refused = (t0 != t) & ~np.asarray(switchable, dtype=bool)[iy, ix]
                p, q = np.where(refused, 0.0, p), np.where(refused, 0.0, q)
            reward = action_reward(config, p, q, nxt == goal, t0 != t)
            if near_edge is not None:
                reward = reward - config.edge_cost * near_edge[m]
            # A robot already in the goal cell (a start there) has arrived: any action ends it.
            success[a, :grid] = np.where(at_goal, 1.0, p)
            stand[a, :grid] = np.where(at_goal, 0.0, q)
            next_state[a, :grid] = np.where(at_goal, goal, nxt)
            R[:grid, a] = np.where(at_goal, 0.0, reward)
    mdp.R, mdp.success, mdp.next_state, mdp.stand = R, success, next_state, stand
    return mdp


# The topology a change must be clearly better than (CapabilityMdpConfig.topology_doubt).
REFERENCE_TOPOLOGY = "nominal"


def _forward_cell(k, iy, ix, allowed):
    """(whether a forward move from each grid state lands in an allowed cell of the grid, the
    cell's ix, iy)."""
    ny, nx = allowed.shape
    fx, fy = ix + HEADING_STEPS[k, 0], iy + HEADING_STEPS[k, 1]
    on_grid = (fx >= 0) & (fx < nx) & (fy >= 0) & (fy < ny)
    return on_grid & allowed[np.clip(fy, 0, ny - 1), np.clip(fx, 0, nx - 1)], fx, fy


def _reference_motions(capability_map, config: CapabilityMdpConfig, topologies, k, iy, ix, allowed):
    """((p, spread) of forward, turn left, turn right) of the reference topology per grid
    state, for ``topology_doubt``; None when it does not apply."""
    if not config.topology_doubt or config.pessimism <= 0 or REFERENCE_TOPOLOGY not in topologies:
        return None
    r = topologies.index(REFERENCE_TOPOLOGY)
    spreads = _spreads(capability_map, r, k, iy, ix)
    if spreads is None:
        return None
    on_grid, _, _ = _forward_cell(k, iy, ix, allowed)
    p = (capability_map.forward[r, k, iy, ix] * on_grid, capability_map.turn_left[r, k, iy, ix],
         capability_map.turn_right[r, k, iy, ix])
    return tuple((np.asarray(pm, dtype=float), sm) for pm, sm in zip(p, spreads))


def _plan_probabilities(capability_map, config: CapabilityMdpConfig, t: int, k, iy, ix):
    """(forward, turn left, turn right) P(the BLC plans it) per grid state of topology t, from
    a factored model's map; None when the config fixes a share or the map has none."""
    if config.plan_failure_share is not None or getattr(capability_map, "forward_plan", None) is None:
        return None
    return tuple(np.asarray(getattr(capability_map, name)[t, k, iy, ix], dtype=float)
                 for name in ("forward_plan", "turn_left_plan", "turn_right_plan"))


def _spreads(capability_map, t: int, k, iy, ix):
    """(forward, turn left, turn right) the ensemble's spread of success per grid state of
    topology t; None for a map without spreads (single networks, a stub)."""
    if getattr(capability_map, "forward_spread", None) is None:
        return None
    return tuple(np.asarray(getattr(capability_map, name)[t, k, iy, ix], dtype=float)
                 for name in ("forward_spread", "turn_left_spread", "turn_right_spread"))


def _plan_failure_shares(capability_map, config: CapabilityMdpConfig, n_topologies: int) -> np.ndarray:
    """(T, 3) the share of planning failures per topology and kind: the config's, or the
    map's (the model's measurement), 0 where neither says."""
    if config.plan_failure_share is not None:
        return np.full((n_topologies, len(P.KINDS)), float(config.plan_failure_share))
    measured = getattr(capability_map, "plan_failure_share", None)
    if measured is None:
        return np.zeros((n_topologies, len(P.KINDS)))
    measured = np.asarray(measured, dtype=float).reshape(n_topologies, len(P.KINDS))
    return np.clip(np.nan_to_num(measured, nan=0.0), 0.0, 1.0)


def forbid_action(mdp: CapabilityMdp, state: int, action: int) -> None:
    """Makes one action fail from one state, in place: what the TLC learns when the BLC could
    not plan it from there (the robot stands where it was; the action leads to the failure
    state from now on, and its reward is a failed action's)."""
    if not (0 <= state < mdp.goal_state):
        raise bad_value("state", state, f"expected a grid state 0..{mdp.goal_state - 1}")
    if not (0 <= action < mdp.success.shape[0]):
        raise bad_value("action", action, f"expected an action 0..{mdp.success.shape[0] - 1}")
    t0 = np.unravel_index(state, mdp.grid_shape)[0]
    config = mdp.config
    if mdp.stand is not None:
        mdp.stand[action, state] = 0.0
    mdp.success[action, state] = 0.0
    mdp.next_state[action, state] = mdp.failure_state
    mdp.R[state, action] = action_reward(config, 0.0, 0.0, False, t0 != action // len(MOTIONS))


def stance_outcomes(model, heightmap, x: float, y: float, heading: int, topology: str, feet_W) -> np.ndarray:
    """(3, 3): for the moves of MOTIONS (forward one cell along ``heading``, turn left, turn
    right) in ``topology``, from the robot's pose (x, y) facing heading k and standing on
    ``feet_W`` (6, 3) in the world (the measured or the plan's stance, not the topology's
    nominal footholds the map assumes), the model's (P(walked), P(the BLC plans it), the
    ensemble's spread of P(walked)); a model without a plan output or spread answers 1 and 0."""
    from qz_drake.capability import patches as P
    from qz_drake.capability.model_base import pose_inputs

    yaw = float(P.heading_yaw(int(heading)))
    out = np.zeros((3, 3))
    move = "orthogonal" if int(heading) % 2 == 0 else "diagonal"
    for m, kind in enumerate((move, "turn")):
        patch, feet = (a[None] for a in pose_inputs(heightmap, x, y, yaw, kind, feet_W))
        rows = (0,) if m == 0 else (1, 2)  # a turn's answers are (left, right)
        if hasattr(model, "success_all"):
            success, plan, spread = model.success_all(patch, {topology: feet}, kind)[topology]
        else:  # a model with only ``success`` (a stub): no plan output, no spread
            directions = np.array([P.TURN_LEFT, P.TURN_RIGHT])[:, None] if kind == "turn" else None
            success = model.success(np.stack([patch] * len(rows)) if kind == "turn" else patch,
                                    np.stack([feet] * len(rows)) if kind == "turn" else feet, kind, topology,
                                    direction=directions)
            plan = spread = None
        success = np.reshape(success, (len(rows),))
        plan = np.ones(len(rows)) if plan is None else np.reshape(plan, (len(rows),))
        spread = np.zeros(len(rows)) if spread is None else np.reshape(spread, (len(rows),))
        for i, r in enumerate(rows):
            out[r] = (success[i], plan[i], spread[i])
    return out


def set_stance(mdp: CapabilityMdp, state: int, outcomes: np.ndarray) -> dict:
    """Replaces, in place, the moves of ``state``'s own topology from that state with what the
    robot's stance gives them (``outcomes``: stance_outcomes). A refusal predicted from the
    stance is weighed as the map weighs refusals: the share ``1 - plan_failure_risk`` of it
    leaves the robot standing, valued by the best other action (the BLC is deterministic, and
    the TLC goes round a refused action instead of retrying it), the rest counts as a failure;
    at the tuned risk 1 every predicted refusal is a failure, as it was before the risk applied
    here. (Counted as a failure at a lower risk, the robot's own moves looked worse than the
    same moves from every other state, and the policy turned back and forth: in TLC-only walks of
    the 24 tuning tasks at risk 0, 11 never reached the goal in 80 missions.) Actions already
    forbidden (forbid_action) stay forbidden. The success is doubted by the spread as the map's
    is (``pessimism``), and a turn beside an edge loses the map's share (``turn_edge_risk``);
    ``topology_doubt``'s comparison with nominal is not made here (the
    robot's own topology's moves, nominal's nearly always). Returns what it replaced, for
    :func:`restore_actions`."""
    if not (0 <= state < mdp.goal_state):
        raise bad_value("state", state, f"expected a grid state 0..{mdp.goal_state - 1}")
    ix, iy, _, topology = mdp.unravel(state)
    if (ix, iy) == mdp.goal_cell:
        return {}
    config = mdp.config
    t = mdp.topologies.index(topology)
    saved = {}
    for m in range(len(MOTIONS)):
        a = t * len(MOTIONS) + m
        nxt = int(mdp.next_state[a, state])
        if nxt == mdp.failure_state:  # forbidden, or a move off the map
            continue
        saved[a] = (float(mdp.success[a, state]), None if mdp.stand is None else float(mdp.stand[a, state]),
                    float(mdp.R[state, a]))
        # What the reward holds beyond the outcomes' (an edge's cost, an arrival's: charge_arrivals) stays.
        extra = saved[a][2] - action_reward(config, saved[a][0], saved[a][1] or 0.0, nxt == mdp.goal_state, False)
        p = float(np.clip(outcomes[m, 0] - config.pessimism * outcomes[m, 2], 0.0, 1.0))
        if mdp.turn_risk is not None and m > 0:
            p *= 1.0 - float(mdp.turn_risk[iy, ix])
        q = 0.0
        if mdp.stand is not None:
            q = float(np.clip(1.0 - outcomes[m, 1], 0.0, 1.0 - p)) * (1.0 - config.plan_failure_risk)
            mdp.stand[a, state] = q
        mdp.success[a, state] = p
        mdp.R[state, a] = action_reward(config, p, q, nxt == mdp.goal_state, False) + extra
    return {state: saved}


def charge_arrivals(mdp: CapabilityMdp, ix: int, iy: int, cost: float) -> int:
    """Charges, in place, every forward move into cell (ix, iy) ``cost`` more (times its
    success: the arrival's expected cost), from every cell, heading and topology; returns how
    many moves it charged. What CapabilityVIPlanner's ``revisit_cost`` charges for each time
    the robot arrived in a cell, so that a replan goes on elsewhere rather than back and forth."""
    T, K, ny, nx = mdp.grid_shape
    if not (0 <= ix < nx and 0 <= iy < ny):
        raise bad_value("cell", [ix, iy], f"off the planning grid of {nx} x {ny} cells")
    grid = mdp.goal_state
    into = [mdp.state(ix, iy, k, t) for t in mdp.topologies for k in range(K)]
    charged = 0
    for t in range(T):
        a = t * len(MOTIONS)  # the forward move of topology t
        nxt = mdp.next_state[a, :grid]
        hits = np.flatnonzero(np.isin(nxt, into))
        mdp.R[hits, a] -= cost * mdp.success[a, hits]
        charged += len(hits)
    return charged


def restore_actions(mdp: CapabilityMdp, saved: dict) -> None:
    """Undoes :func:`set_stance` (its return value), in place; an action forbidden since stays
    forbidden."""
    for state, actions in saved.items():
        for a, (success, stand, reward) in actions.items():
            if mdp.next_state[a, state] == mdp.failure_state:
                continue
            mdp.success[a, state] = success
            if stand is not None:
                mdp.stand[a, state] = stand
            mdp.R[state, a] = reward


def step_state_action(mdp: CapabilityMdp, step) -> tuple[int, int]:
    """(state, action) of a PathStep of this MDP's grid."""
    ix, iy = mdp.cell_of(step.x, step.y, field="step")
    return (mdp.state(ix, iy, step.heading, step.topology),
            mdp.topologies.index(step.action_topology) * len(MOTIONS) + MOTIONS.index(step.motion))


@dataclasses.dataclass
class PathStep:
    """One action of a planned path, from the state it starts in."""

    # Cell centre the action starts from. [m]
    x: float
    y: float
    # Heading index k (yaw = k * 45 deg) before the action.
    heading: int
    # Topology before the action and the action's topology.
    topology: str
    action_topology: str
    # forward, turn_left or turn_right.
    motion: str
    # Predicted success probability of the action.
    success: float
    # Predicted probability that the BLC finds no plan for it (the robot stands; the TLC goes
    # round); the rest of 1 - success is the walk failing.
    stand: float = 0.0

    @property
    def fall(self) -> float:
        """Predicted probability that the action ends the walk (a fall, a leg in the terrain...)."""
        return max(0.0, 1.0 - self.success - self.stand)


@dataclasses.dataclass
class CapabilityPlan:
    """A solved capability MDP and the most likely path from a start to the goal."""

    mdp: CapabilityMdp
    solution: ValueIterationResult
    steps: list[PathStep]
    # Whether following the policy's successful outcomes reaches the goal.
    reaches_goal: bool
    # Product of the steps' success probabilities.
    success_probability: float
    # The map the MDP was built from and its edge clearances (None where none were needed):
    # what expected_fall_free rebuilds the MDP from.
    capability_map: object | None = None
    edge_clearance: np.ndarray | None = None

    def utility_map(self, topology: str | None = None) -> np.ndarray:
        """(ny, nx) best V over headings (and topologies, or of one topology)."""
        V = self.solution.V[:self.mdp.goal_state].reshape(self.mdp.grid_shape)
        if topology is not None:
            return V[self.mdp.topologies.index(topology)].max(axis=0)
        return V.max(axis=(0, 1))

    @property
    def cells(self) -> np.ndarray:
        """(n, 2) cell centres the path visits, start and goal included, without repeats. [m]"""
        points = [(s.x, s.y) for s in self.steps]
        if self.reaches_goal:
            gx, gy = self.mdp.goal_cell
            points.append((float(self.mdp.xs[gx]), float(self.mdp.ys[gy])))
        out = [p for i, p in enumerate(points) if i == 0 or p != points[i - 1]]
        return np.array(out, dtype=float).reshape(-1, 2)

    @property
    def topology_changes(self) -> int:
        return sum(s.topology != s.action_topology for s in self.steps)

    @property
    def fall_free_probability(self) -> float:
        """Predicted chance that no action of the path ends the walk, the TLC going round what
        the BLC cannot plan: the product of the steps' 1 - fall."""
        return fall_free_probability(self.steps)

    def expected_fall_free(self) -> float:
        """The model's own estimate that the path walks without an action ending the walk, the
        TLC going round what the BLC cannot plan: :attr:`fall_free_probability` of the same
        steps with the map's mean success (``pessimism`` 0: no ensemble doubt) and its planning
        failures as they are (``plan_failure_risk`` 0); the turns' ``turn_edge_risk`` stays. The
        plan itself is chosen on the doubted values; this is what it predicts of its walk.
        Needs the plan's ``capability_map`` (plan, plan_on_map keep it)."""
        if self.capability_map is None:
            raise bad_value("capability_map", None, "the plan keeps no map to judge its steps by (plan_on_map's "
                                                    "plans do)")
        if not self.steps:
            return 1.0
        config = dataclasses.replace(self.mdp.config, pessimism=0.0, plan_failure_risk=0.0)
        gx, gy = self.mdp.goal_cell
        mean = build_capability_mdp(self.capability_map, (float(self.mdp.xs[gx]), float(self.mdp.ys[gy])), config,
                                    edge_clearance=self.edge_clearance)
        stand = np.zeros_like(mean.success) if mean.stand is None else mean.stand
        kept = [1.0 - max(0.0, 1.0 - mean.success[a, s] - stand[a, s])
                for s, a in (step_state_action(mean, step) for step in self.steps)]
        return float(np.prod(kept))


def fall_free_probability(steps) -> float:
    """Product of the PathSteps' 1 - fall (1 for no steps)."""
    return float(np.prod([1.0 - s.fall for s in steps])) if steps else 1.0


def most_likely_path(mdp: CapabilityMdp, solution: ValueIterationResult, start_state: int,
                     max_steps: int | None = None) -> tuple[list[PathStep], bool, float]:
    """Follows the greedy policy from ``start_state``, taking each action's successful outcome,
    until the goal, a revisited state (the policy loops) or ``max_steps`` (default: the number
    of grid states). Returns (steps, reaches_goal, product of success probabilities)."""
    max_steps = mdp.goal_state if max_steps is None else int(max_steps)
    steps, seen, s, probability = [], set(), int(start_state), 1.0
    if s < mdp.goal_state and mdp.unravel(s)[:2] == mdp.goal_cell:
        return steps, True, probability
    while s < mdp.goal_state and s not in seen and len(steps) < max_steps:
        seen.add(s)
        a = int(solution.policy[s])
        ix, iy, k, t = mdp.unravel(s)
        action_topology, motion = mdp.action(a)
        p = float(mdp.success[a, s])
        q = 0.0 if mdp.stand is None else float(mdp.stand[a, s])
        steps.append(PathStep(float(mdp.xs[ix]), float(mdp.ys[iy]), k, t, action_topology, motion, p, q))
        probability *= p
        s = int(mdp.next_state[a, s])
    return steps, s == mdp.goal_state, probability


def path_value(mdp: CapabilityMdp, solution: ValueIterationResult, steps) -> float:
    """The value of walking ``steps`` (PathSteps, each starting where the one before ends), as
    solve_capability_mdp values a policy: each action's reward, with its success the next
    step's value, its planning failure the best other action's Q there (the TLC goes round),
    its fall nothing; after the last step the state's value (0 at the goal). A path of the
    greedy policy is worth V(start) (within the solve's epsilon); another path less, by how
    much the policy prefers its own."""
    if not steps:
        raise bad_value("steps", steps, "expected at least one PathStep")
    gamma = float(mdp.config.discount)
    pairs = [step_state_action(mdp, s) for s in steps]
    for (s, a), (n, _) in zip(pairs[:-1], pairs[1:]):
        if int(mdp.next_state[a, s]) not in (n, mdp.failure_state):
            raise bad_value("steps", f"state {s} action {a}", f"does not lead to the next step's state {n}")
    s, a = pairs[-1]
    end = int(mdp.next_state[a, s])
    value = 0.0 if end >= mdp.goal_state else float(solution.V[end])
    for s, a in reversed(pairs):
        p = float(mdp.success[a, s])
        q = 0.0 if mdp.stand is None else float(mdp.stand[a, s])
        others = np.delete(solution.Q[s], a)
        value = float(mdp.R[s, a]) + gamma * (p * value + q * (float(others.max()) if others.size else 0.0))
    return value


def most_probable_path(mdp: CapabilityMdp, start_state: int) -> tuple[list[PathStep], bool, float]:
    """The path from ``start_state`` to the goal whose actions all walk with the highest
    probability (the largest product of their success: Dijkstra on -log p, the best action
    between two states kept), as (steps, reaches_goal, that product); ([], False, 0) when no
    path with p > 0 reaches the goal.

    CapPlanner's TLC follows it where the MDP's policy does not reach the goal: there every
    way to the goal is worth less to the MDP than turning in place for ever (a long or risky
    route against the failure's reward), yet declining the task fails it for certain;
    whether the path is worth walking is then the TLC's ``min_route_success``."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    grid = int(mdp.goal_state)
    start_state = int(start_state)
    if mdp.unravel(start_state)[:2] == mdp.goal_cell:
        return [], True, 1.0
    p = np.asarray(mdp.success[:, :grid], dtype=float)
    nxt = np.asarray(mdp.next_state[:, :grid])
    a_idx, s_idx = np.nonzero((p > 0.0) & (nxt <= grid) & (nxt != np.arange(grid)))
    n_idx = nxt[a_idx, s_idx]
    # Strictly positive weights: the graph keeps no explicit zeros.
    weights = -np.log(np.minimum(p[a_idx, s_idx], 1.0)) + 1e-12
    order = np.lexsort((weights, n_idx, s_idx))  # per (state, successor) the likeliest first
    first = np.ones(len(order), bool)
    first[1:] = (s_idx[order][1:] != s_idx[order][:-1]) | (n_idx[order][1:] != n_idx[order][:-1])
    keep = order[first]
    graph = csr_matrix((weights[keep], (s_idx[keep], n_idx[keep])), shape=(grid + 1, grid + 1))
    distance, previous = dijkstra(graph, indices=start_state, return_predecessors=True)
    if not np.isfinite(distance[grid]):
        return [], False, 0.0
    chain = [grid]
    while chain[-1] != start_state:
        chain.append(int(previous[chain[-1]]))
    chain.reverse()
    steps, probability = [], 1.0
    for s, n in zip(chain[:-1], chain[1:]):
        actions = np.flatnonzero(nxt[:, s] == n)
        a = int(actions[np.argmax(p[actions, s])])
        ix, iy, k, t = mdp.unravel(s)
        action_topology, motion = mdp.action(a)
        q = 0.0 if mdp.stand is None else float(mdp.stand[a, s])
        steps.append(PathStep(float(mdp.xs[ix]), float(mdp.ys[iy]), k, t, action_topology, motion, float(p[a, s]), q))
        probability *= float(p[a, s])
    return steps, True, probability


def solve_capability_mdp(mdp: CapabilityMdp, V0=None) -> ValueIterationResult:
    """Eq. 9-10 on the capability MDP, a planning failure's stay valued by the best *other*
    action from the same state (see the module docstring); returns the values, the greedy
    policy and Q.

    Iterates Eq. 9 in Q form, Q(s, a) = r + gamma (p V(n) + q max_{b != a} Q(s, b)), and, with
    ``config.policy_evaluation`` (the default), values each new greedy policy before the next
    improvement (modified policy iteration, Puterman 6.5; see the kernels below), which
    removes the slow tail where values settle at gamma per iteration. Stops when one iteration
    changes no Q(s, a) by more than epsilon (1 - gamma) / (2 gamma): Q is then within epsilon / 2
    of the fixed point, whichever way it got there. ``iterations`` counts improvements and
    evaluations. Without planning failures and without policy evaluation it is
    :func:`value_iteration`'s Eq. 9.

    ``V0`` defaults to the failure reward in every grid state (0 in the absorbing ones): far from
    the goal the values end near it, and starting there took a third of the iterations that
    zeros took on the 20 m world, to the same policy (BENCHMARKS "plan"). Any start converges
    to the same fixed point; only the iteration count differs.
    """
    config = mdp.config
    A, S = mdp.success.shape
    gamma = float(config.discount)
    if V0 is None:
        V0 = np.zeros(S)
        V0[:mdp.goal_state] = config.failure_reward
    stand = np.zeros((A, S)) if mdp.stand is None else np.asarray(mdp.stand, dtype=float)
    if not stand.any() and not config.policy_evaluation:
        return value_iteration(mdp.P, mdp.R, gamma, epsilon=config.epsilon, max_iter=config.max_iter, V0=V0)
    kernels = _kernels()
    from qz_drake.threads import set_numba_threads

    set_numba_threads()
    # The MDP's arrays state-major, as the compiled kernels read them: (S, A). (Built
    # state-major, the arrays took a 100 m plan's build 3.2 s instead of 0.7 s: a column written
    # at a time visits every cache line 18 times; the copies here cost less.)
    arrays = (np.ascontiguousarray(np.asarray(mdp.success, dtype=float).T), np.ascontiguousarray(stand.T),
              np.ascontiguousarray(np.asarray(mdp.R, dtype=float)), np.ascontiguousarray(mdp.next_state.T, dtype=np.int64))
    threshold = config.epsilon * (1.0 - gamma) / (2.0 * gamma) if gamma < 1.0 else config.epsilon
    first_absorbing, failure = int(mdp.goal_state), int(mdp.failure_state)
    no_policy = np.empty(0, np.int64)

    def backup(V, best, second, out):
        # Q = r + gamma P V, from the arrays P is made of (the same entries: success to the next
        # state, the stay, the rest to failure); the stay is worth V(s), except for the action
        # that is best in s, whose stay is worth the second best.
        return kernels.backup(*arrays, V, best, second, gamma, first_absorbing, failure, out)

    Q, spare = np.empty((S, A)), np.empty((S, A))
    backup(np.array(V0, dtype=float).reshape(S), no_policy, np.empty(0), Q)
    V, second = np.empty(S), np.empty(S)
    best, runner_up = np.empty(S, np.int64), np.empty(S, np.int64)
    change, converged, iterations, evaluated, evaluations = np.inf, False, 0, None, 0
    for iterations in range(1, int(config.max_iter) + 1):
        # V, the greedy action (the lowest index among ties), the best other action's Q and
        # that action. After an evaluation, policy iteration's rule: keep the evaluated action
        # unless another is better by more than a rounding error (a tie between two turns
        # need not be evaluated again).
        kernels.improve(Q, no_policy if evaluated is None else evaluated, V, best, second, runner_up)
        if (config.policy_evaluation and evaluations < MAX_EVALUATIONS
                and (evaluated is None or np.any(best != evaluated))):
            # A new greedy policy: value it (policy iteration's evaluation step) and improve on
            # that; Eq. 9 alone creeps there at gamma per iteration far from the goal.
            evaluated, evaluations = best.copy(), evaluations + 1
            values, stay = V, None
            for _ in range(GREEDY_PASSES):
                values, stay = kernels.greedy_values(*arrays, evaluated, runner_up, values, gamma, first_absorbing)
            backup(values, evaluated, stay, Q)
            continue
        # One iteration of Eq. 9 in Q form (the best action's stay worth the second best). Its
        # residual over every Q(s, a) below the threshold: Q is within epsilon / 2 of the
        # fixed point and the greedy policy epsilon-optimal.
        backup(V, best, second, spare)
        change = kernels.largest_change(spare, Q)
        Q, spare, evaluated = spare, Q, None
        if change < threshold:
            converged = True
            break
    return ValueIterationResult(V=Q.max(axis=1), policy=np.argmax(Q, axis=1), Q=Q,
                                iterations=iterations, max_change=change, converged=converged)


# The policy evaluation (modified policy iteration, solve_capability_mdp): in state s the best
# action a reaches n_a with probability p_a, stays with q_a and is then worth the runner-up b's
# Q, whose own stay is worth V(s):
# V(s) = r_a + gamma (p_a V(n_a) + q_a (r_b + gamma (p_b V(n_b) + q_b V(s)))). With V(n_b) held
# at the previous pass's values this is V(s) = c(s) + g(s) V(n_a(s)): one successor per state,
# solved exactly along its chains (greedy_values below), GREEDY_PASSES times.
_KERNELS = None


def _kernels():
    """The solver's compiled loops (numba is imported and they are compiled, or read from its
    cache, on first use)."""
    global _KERNELS
    if _KERNELS is None:
        _KERNELS = _compile_kernels()
    return _KERNELS


def _compile_kernels():
    import types

    import numba

    # The states' loops split over the free cores (threads.set_numba_threads, called by
    # solve_capability_mdp): each state's entries are its own, so the numbers do not depend on
    # the split.
    @numba.njit(cache=True, parallel=True)
    def backup(success, stand, r, next_state, V, best, second, gamma, first_absorbing, failure, out):
        """out[s, a] = r + gamma (p V(n) + (1 - p - q) V(failure) + q stay), the stay worth
        V(s), or second[s] for a == best[s] (when a policy is given); V(s) itself from an
        absorbing state."""
        S, A = success.shape
        with_policy = best.shape[0] == S
        v_failure = V[failure]
        for s in numba.prange(S):
            if s >= first_absorbing:
                for a in range(A):
                    out[s, a] = r[s, a] + gamma * V[s]
                continue
            for a in range(A):
                p, q = success[s, a], stand[s, a]
                stay = second[s] if with_policy and best[s] == a else V[s]
                out[s, a] = r[s, a] + gamma * (p * V[next_state[s, a]] + (1.0 - p - q) * v_failure + q * stay)
        return out

    @numba.njit(cache=True)
    def largest_change(new, old):
        """max |new - old| over every entry (NaN if any is NaN), without temporaries."""
        top = 0.0
        for s in range(new.shape[0]):
            for a in range(new.shape[1]):
                d = abs(new[s, a] - old[s, a])
                if d > top or d != d:
                    top = d
                    if d != d:
                        return d
        return top

    @numba.njit(cache=True, parallel=True)
    def improve(Q, evaluated, V, best, second, runner_up):
        """Per state: the greedy action (the first among ties; the evaluated one where it is
        within a rounding error of the best), its Q, the best other Q and its action."""
        S, A = Q.shape
        keep = evaluated.shape[0] == S
        for s in numba.prange(S):
            top, b = Q[s, 0], 0
            for a in range(1, A):
                if Q[s, a] > top:
                    top, b = Q[s, a], a
            if keep:
                e = evaluated[s]
                if Q[s, e] >= top - 1e-9 * max(1.0, abs(top)):
                    b = e
            other, o = -np.inf, -1
            for a in range(A):
                if a != b and Q[s, a] > other:
                    other, o = Q[s, a], a
            V[s], best[s], second[s], runner_up[s] = Q[s, b], b, other, o

    @numba.njit(cache=True, parallel=True)
    def greedy_values(success, stand, r, next_state, best, runner_up, V, gamma, first_absorbing):
        """(V, the best action's stay: the runner-up's Q) of the greedy policy, V(s) = c(s) +
        g(s) V(n(s)) solved exactly. The successor graph is functional: from any state the
        chain ends in a cycle (an absorbing state's is its self-loop). Each chain is walked once;
        a new cycle's first state is solved in closed form, V = C / (1 - G) with C and G
        composed around it (G < 1: the policy is discounted), and the walk's states are then
        valued backwards from wherever it stopped. O(S), where pointer doubling took
        log2(horizon) rounds of gathers over every state."""
        S = best.shape[0]
        c, g = np.empty(S), np.empty(S)
        n = np.empty(S, np.int64)
        rest_b, q_b = np.empty(S), np.empty(S)
        for s in numba.prange(S):
            if s >= first_absorbing:
                c[s], g[s], n[s], rest_b[s], q_b[s] = 0.0, 0.0, s, 0.0, 0.0
                continue
            a, b = best[s], runner_up[s]
            q_a, q_b[s] = stand[s, a], stand[s, b]
            # The runner-up's Q without its stay, which is worth V(s) (solved for below).
            rest_b[s] = r[s, b] + gamma * success[s, b] * V[next_state[s, b]]
            loop = 1.0 - gamma * gamma * q_a * q_b[s]
            c[s] = (r[s, a] + gamma * q_a * rest_b[s]) / loop
            g[s] = gamma * success[s, a] / loop
            n[s] = next_state[s, a]
        values = np.empty(S)
        state = np.zeros(S, np.int8)  # 0 unseen, 1 on the current walk, 2 valued
        walk = np.empty(S, np.int64)
        for first in range(S):
            if state[first] == 2:
                continue
            top, s = 0, first
            while state[s] == 0:
                state[s] = 1
                walk[top] = s
                top += 1
                s = n[s]
            if state[s] == 1:  # a new cycle through s: V(s) = C + G V(s)
                C, G, u = 0.0, 1.0, s
                while True:
                    C += G * c[u]
                    G *= g[u]
                    u = n[u]
                    if u == s:
                        break
                values[s] = C / (1.0 - G)
                state[s] = 2
            for i in range(top - 1, -1, -1):
                u = walk[i]
                if state[u] != 2:
                    values[u] = c[u] + g[u] * values[n[u]]
                    state[u] = 2
        return values, rest_b + gamma * q_b * values

    return types.SimpleNamespace(backup=backup, improve=improve, greedy_values=greedy_values,
                                 largest_change=largest_change)


def plan_on_map(capability_map, start_xy, start_heading: int, goal_xy, *, start_topology: str = "nominal",
                config: CapabilityMdpConfig | None = None, switchable: np.ndarray | None = None,
                on_map: np.ndarray | None = None, edge_clearance: np.ndarray | None = None) -> CapabilityPlan:
    """Builds the MDP of a CapabilityMap, solves it by value iteration and extracts the most
    likely path from the start (x, y, heading index, topology) to the goal."""
    mdp = build_capability_mdp(capability_map, goal_xy, config, switchable, on_map, edge_clearance)
    if start_topology not in mdp.topologies:
        raise bad_value("start_topology", start_topology, f"expected one of {', '.join(mdp.topologies)}")
    ix, iy = mdp.cell_of(*start_xy, field="start")
    solution = solve_capability_mdp(mdp)
    steps, reaches, probability = most_likely_path(mdp, solution, mdp.state(ix, iy, start_heading, start_topology))
    return CapabilityPlan(mdp, solution, steps, reaches, probability, capability_map, edge_clearance)


def plan(model, heightmap, start_xy, start_heading: int, goal_xy, *, start_topology: str = "nominal",
         config: CapabilityMdpConfig | None = None) -> CapabilityPlan:
    """Plans with a capability model (anything with CapabilityModel's ``success``) on a
    heightmap: the whole map's success probabilities in one batched evaluation, then
    :func:`plan_on_map`."""
    from qz_drake.capability.model import predict_map

    config = (config or CapabilityMdpConfig()).check()
    xmin, xmax, ymin, ymax = heightmap.bounds
    for name, xy in (("start_xy", start_xy), ("goal_xy", goal_xy)):
        # Off the map, the MDP would plan to the nearest cell on it and say nothing.
        if not (xmin <= xy[0] <= xmax and ymin <= xy[1] <= ymax):  # NaN too
            raise bad_value(name, tuple(float(v) for v in xy), f"off the map (x in [{xmin:g}, {xmax:g}], "
                                                                f"y in [{ymin:g}, {ymax:g}])")
    # The grid is anchored on the start: the robot starts at a cell centre, as the grid world has it.
    capability_map = predict_map(model, heightmap, config.topologies or None, cell_size=config.cell_size,
                                 anchor=start_xy, stance=config.stance)
    return plan_on_map(capability_map, start_xy, start_heading, goal_xy, start_topology=start_topology,
                       config=config, switchable=switchable_cells(heightmap, capability_map.xs,
                                                                  capability_map.ys, config),
                       on_map=cells_on_map(heightmap, capability_map.xs, capability_map.ys),
                       edge_clearance=edge_clearances(heightmap, capability_map.xs, capability_map.ys, config)
                       if config.needs_edge_clearance else None)
