"""The per-node load model of a population of plans: one place where usage, requests, uplink
traffic and contention are summed per node (``np.bincount`` over the flattened population,
offset ``p * N``), shared by every objective, the constraints, the repair and local search.

Readings of multi-robot-edge-cloud-scheduling III-D (the paper's symbols in brackets):

- *usage* ``U(m_i, n_j, r)``: for CPU the expected use ``activation_i * cpu_use_ij`` (a module
  only computes while it is active, "GA-based with TA"); for memory the requested bytes.
- *requested* utilisation (for limits and reserves): CPU requests, memory, GPUs.
- resources are made commensurable by dividing each node's usage by its own limit ``L_j^r``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from functools import cached_property

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from fogfleet.api.v1alpha1.base import MBPS
from fogfleet.domain.problem import Allocation, Problem

__all__ = ["NODE_SUMS", "UPLINK_SHARE", "Evaluation", "miss_probability"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

# A robot's off-board traffic may use at most this share of its uplink (hard constraint).
UPLINK_SHARE = 0.8

# Gauss-Hermite nodes/weights for E[f(Z)], Z ~ N(0, 1) (probabilists' form).
_GH_NODES, _GH_WEIGHTS = np.polynomial.hermite_e.hermegauss(9)
_GH_X: F64 = np.asarray(_GH_NODES, dtype=np.float64)[:, None]  # (9, 1): one row per node
_GH_W: F64 = np.asarray(_GH_WEIGHTS / np.sqrt(2.0 * np.pi), dtype=np.float64)[:, None]


def _phi(z: F64) -> F64:
    """Standard normal CDF."""
    return np.asarray(ndtr(z), dtype=np.float64)


def miss_probability(mean: F64, std: F64, cycle: F64) -> F64:
    """P(t_cycle > T) for a normal cycle time (mean, std); a step function where std == 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (mean - cycle) / std
    step = (mean > cycle).astype(np.float64)
    return np.where(std > 0, _phi(np.where(std > 0, z, 0.0)), step)


class Evaluation:
    """Intermediate arrays of one population, computed once and shared by the objectives."""

    def __init__(self, problem: Problem, X: NDArray[np.integer], allocation: Allocation) -> None:
        x = np.asarray(X, dtype=np.int64)
        if x.ndim == 1:
            x = x[None, :]
        self.problem = problem
        self.alloc = allocation
        self.P, self.I = x.shape
        self.N = problem.n_nodes
        self.valid = x >= 0
        self.x = np.where(self.valid, x, 0)
        self._rows = np.arange(self.I)[None, :]
        self._flat = (self.x + self.N * np.arange(self.P)[:, None]).ravel()
        self.robots = np.flatnonzero(problem.tier == 0)
        self.remote = np.flatnonzero(problem.tier > 0)

    @classmethod
    def of_node_sums(
        cls, problem: Problem, allocation: Allocation, sums: Mapping[str, F64]
    ) -> Evaluation:
        """An evaluation of P plans known only by their per-node sums ``sums`` (P, N each;
        the keys of ``NODE_SUMS``), as a local search gets them by updating a parent's sums.
        Only the objectives of ``NODE_OBJECTIVES`` and ``node_constraints`` may be called."""
        missing = set(NODE_SUMS) - set(sums)
        if missing:
            raise KeyError(f"missing per-node sum(s): {', '.join(sorted(missing))}")
        ev = cls.__new__(cls)
        ev.problem = problem
        ev.alloc = allocation
        ev.P, ev.N = next(iter(sums.values())).shape
        ev.I = problem.n_instances
        ev.robots = np.flatnonzero(problem.tier == 0)
        ev.remote = np.flatnonzero(problem.tier > 0)
        for k in NODE_SUMS:
            ev.__dict__[k] = sums[k]
        return ev

    # -- helpers --------------------------------------------------------------------------
    def gather(self, a: F64) -> F64:
        """``a[i, x_i]`` per plan, 0 where the instance is not placed."""
        return np.where(self.valid, a[self._rows, self.x], 0.0)

    def per_node(self, w: F64) -> F64:
        """Sum of per-instance weights ``w`` (P, I) on each node: (P, N)."""
        wv = np.where(self.valid, w, 0.0).ravel()
        out = np.bincount(self._flat, weights=wv, minlength=self.P * self.N)
        return np.asarray(out, dtype=np.float64).reshape(self.P, self.N)

    # -- shared arrays --------------------------------------------------------------------
    @cached_property
    def request(self) -> F64:
        return self.gather(self.alloc.cpu_request)

    @cached_property
    def use(self) -> F64:
        return self.gather(self.alloc.cpu_use)

    @cached_property
    def _held(self) -> NDArray[np.bool_] | None:
        """(P, I) instances on their home node whose demand there is the robot's fallback
        reserve (``Problem.fallback_reserve``); None when the fleet has no fallbacks."""
        p = self.problem
        if not p.fallback_rows.size:
            return None
        held = self.valid & p.held_at_home[None, :] & (self.x == p.home[None, :])
        return np.asarray(held, dtype=bool)

    def _requested(self, w: F64, r: int) -> F64:
        """Per-node requests of resource ``r`` from per-instance weights ``w`` (P, I): each
        robot's fallback reserve, plus what its fallback instances on board need beyond
        their share of it, plus everything else."""
        held = self._held
        if held is None:
            return self.per_node(w)
        p = self.problem
        share = p.fallback_share(self.alloc)[:, r]
        reserve = p.fallback_reserve(self.alloc)[:, r]
        return self.per_node(np.where(held, w - share[None, :], w)) + reserve[None, :]

    @cached_property
    def cpu_requested(self) -> F64:
        return self._requested(self.request, 0)

    @cached_property
    def mem_requested(self) -> F64:
        return self._requested(np.broadcast_to(self.problem.memory, (self.P, self.I)), 1)

    @cached_property
    def gpu_requested(self) -> F64:
        return self._requested(np.broadcast_to(self.problem.gpu, (self.P, self.I)), 2)

    @cached_property
    def cpu_expected(self) -> F64:
        """Expected CPU use per node: sum of activation * cpu_use (P, N)."""
        return self.per_node(self.problem.activation[None, :] * self.use)

    @cached_property
    def cpu_onboard(self) -> F64:
        """Expected CPU use per node beyond what the robots already hold for fallbacks (P, N):
        an instance on its robot whose standby's share is in the robot's reserve
        (``Problem.held_at_home``) adds only its expected use above that share. F1 counts
        this: the reserve is held whatever the plan, so running the module on the CPU its
        standby already holds costs the robot nothing more."""
        w = self.problem.activation[None, :] * self.use
        held = self._held
        if held is not None:
            share = self.problem.fallback_share(self.alloc)[:, 0]
            w = np.where(held, np.maximum(w - share[None, :], 0.0), w)
        return self.per_node(w)

    @cached_property
    def cpu_peak(self) -> F64:
        """CPU use per node if every instance there were active at once (P, N)."""
        return self.per_node(self.use)

    @cached_property
    def kappa(self) -> F64:
        """CPU contention factor per node, kappa_j = max(1, load_j / cap_j) (P, N)."""
        return np.maximum(1.0, self.cpu_expected / self.problem.capacity[None, :, 0])

    @cached_property
    def exe(self) -> F64:
        return self.gather(self.alloc.exe_mean)

    @cached_property
    def exe_std(self) -> F64:
        return self.gather(self.alloc.exe_std)

    @cached_property
    def net(self) -> F64:
        return self.gather(self.problem.net_mean)

    @cached_property
    def net_std(self) -> F64:
        return self.gather(self.problem.net_std)

    @cached_property
    def offboard_traffic(self) -> F64:
        """Bit/s each robot node exchanges over its uplink (P, N; 0 for non-robots)."""
        home = self.problem.home
        off = self.valid & (home[None, :] >= 0) & (self.x != home[None, :])
        w = np.where(off, self.problem.traffic[None, :], 0.0).ravel()
        h = np.where(home >= 0, home, 0)
        flat = (h[None, :] + self.N * np.arange(self.P)[:, None]).ravel()
        out = np.bincount(flat, weights=w, minlength=self.P * self.N)
        return np.asarray(out, dtype=np.float64).reshape(self.P, self.N)

    # -- objectives -----------------------------------------------------------------------
    def onboard(self) -> F64:
        cap = self.problem.capacity[self.robots]
        cpu = self.cpu_onboard[:, self.robots] / cap[None, :, 0]
        mem = self.mem_requested[:, self.robots] / np.maximum(cap[None, :, 1], 1.0)
        return np.asarray((cpu + mem).sum(axis=1), dtype=np.float64)

    def utilisation(self) -> F64:
        """Requested utilisation u_j^r / L_j^r, (P, N, R) over the resources some node has."""
        cap = self.problem.capacity
        parts = [self.cpu_requested / cap[None, :, 0]]
        parts.append(self.mem_requested / np.maximum(cap[None, :, 1], 1.0))
        if cap[:, 2].any() or self.problem.gpu.any():
            # a GPU request on a GPU-less node counts as infinitely over the limit
            with np.errstate(divide="ignore", invalid="ignore"):
                g = np.where(cap[None, :, 2] > 0, self.gpu_requested / cap[None, :, 2], 0.0)
                g = np.where((cap[None, :, 2] == 0) & (self.gpu_requested > 0), np.inf, g)
            parts.append(g)
        return np.stack(parts, axis=2)

    def reserve(self) -> F64:
        return np.asarray(self.utilisation().max(axis=(1, 2)), dtype=np.float64)

    def balance(self) -> F64:
        """F3 within each tier: the edge's spread plus the cloud's. The paper's C_E lumps edge
        and cloud together, which rewards filling a paid cloud to match a busy edge; balancing
        inside a tier spreads load without pulling it across the tier boundary."""
        total = np.zeros(self.P)
        for code in (1, 2):  # domain.problem.TIER_CODE: edge, cloud
            nodes = self.remote[self.problem.tier[self.remote] == code]
            if len(nodes) < 2:
                continue
            cap = self.problem.capacity[nodes]
            total += np.std(self.cpu_expected[:, nodes] / cap[None, :, 0], axis=1)
            total += np.std(self.mem_requested[:, nodes] / np.maximum(cap[None, :, 1], 1.0), axis=1)
            if cap[:, 2].any():
                g = self.gpu_requested[:, nodes] / np.maximum(cap[None, :, 2], 1.0)
                total += np.std(g, axis=1)
        return np.asarray(total, dtype=np.float64)

    def tau(self) -> F64:
        """tau(m_i, n_j) of eq. 5 with the node's contention factor (P, I); 0 if unplaced."""
        k = self.kappa[np.arange(self.P)[:, None], self.x]
        t = (self.net + self.exe * k) / self.problem.cycle[None, :]
        return np.where(self.valid, t, 0.0)

    def missed_cycles(self) -> F64:
        t = self.tau()
        a = self.problem.activation[None, :]
        return np.asarray((a * np.where(t > 1.0, t, 0.0)).sum(axis=1), dtype=np.float64)

    def overlap_demand(self) -> tuple[F64, F64, F64, NDArray[np.bool_]]:
        """Overlap-aware CPU demand on each instance's node while it executes.

        Instance k occupies ``cpu_use_k`` cores with probability b_k = activation_k * duty_k,
        duty_k = min(1, t_exe_k * slowdown_k / T_k) (between cycles a module waits for its next
        period). The demand on i's node while i runs is D = use_i + sum_{k != i} B_k use_k with
        B_k ~ Bernoulli(b_k), approximated as normal and clipped to [use_i, all-active peak].
        Returns (mean, std, peak) of D (P, I each) and the mask of instances whose node can be
        oversubscribed at all (peak > cap); elsewhere the slowdown is exactly 1. Two
        fixed-point rounds couple duty and slowdown.
        """
        pidx = np.arange(self.P)[:, None]
        peak = self.cpu_peak[pidx, self.x]
        cap = self.problem.capacity[:, 0][self.x]
        hot = self.valid & (peak > cap * (1 + 1e-9))
        m = self.use.copy()
        sd = np.zeros_like(m)
        if not hot.any():
            return m, sd, peak, hot
        a = self.problem.activation[None, :]
        cyc = self.problem.cycle[None, :]
        use = self.use
        slow = np.ones((self.P, self.I))
        for _ in range(2):
            duty = np.minimum(1.0, self.exe * slow / cyc)
            b = np.where(self.valid, a * duty, 0.0)
            bu = b * use
            bv = b * (1.0 - b) * use * use
            m = use + self.per_node(bu)[pidx, self.x] - bu
            sd = np.sqrt(np.maximum(self.per_node(bv)[pidx, self.x] - bv, 0.0))
            mh, sh, uh, ph, ch = m[hot], sd[hot], use[hot], peak[hot], cap[hot]
            slow[hot] = self._expect(lambda d: np.maximum(1.0, d / ch), mh, sh, uh, ph)  # noqa: B023
        return m, sd, peak, hot

    @staticmethod
    def _expect(f: Callable[[F64], F64], m: F64, sd: F64, lo: F64, hi: F64) -> F64:
        """E[f(D)] for D ~ N(m, sd) clipped to [lo, hi], by Gauss-Hermite quadrature: ``f``
        sees the nine nodes at once as a (9, n) array (it broadcasts over the first axis)."""
        d = np.clip(m[None, :] + sd[None, :] * _GH_X, lo[None, :], hi[None, :])
        return np.asarray((_GH_W * f(d)).sum(axis=0), dtype=np.float64)

    @cached_property
    def placed_activation(self) -> F64:
        """Each placed instance's activation, 0 where it is not placed (P, I)."""
        return np.where(self.valid, self.problem.activation[None, :], 0.0)

    def per_module(self, w: F64) -> F64:
        """Sum of per-instance weights ``w`` (P, I) over each module's instances: (P, M), M in
        ``Problem.module_names`` order."""
        mod = self.problem.module_index
        n_mod = len(self.problem.module_names)
        flat = (mod[None, :] + n_mod * np.arange(self.P)[:, None]).ravel()
        out = np.bincount(flat, weights=np.ravel(w), minlength=self.P * n_mod)
        return np.asarray(out, dtype=np.float64).reshape(self.P, n_mod)

    @cached_property
    def module_activation(self) -> F64:
        """Each module's placed activation (P, M): the weights of ``miss_rate``."""
        return self.per_module(self.placed_activation)

    def instance_miss(self) -> F64:
        """Predicted miss probability of each instance's active cycles (P, I): the normal
        cycle-time tail at slowdown max(1, D / cap), averaged over the demand D (computed
        once per evaluation: the miss rate, the local search and the reports share it)."""
        return self._instance_miss

    @cached_property
    def _instance_miss(self) -> F64:
        T = np.broadcast_to(self.problem.cycle[None, :], (self.P, self.I))
        q = miss_probability(self.net + self.exe, np.sqrt(self.exe_std**2 + self.net_std**2), T)
        m, sd, peak, hot = self.overlap_demand()
        if hot.any():
            cap = self.problem.capacity[:, 0][self.x][hot]
            net, net_sd, exe, exe_sd, th = (
                self.net[hot],
                self.net_std[hot],
                self.exe[hot],
                self.exe_std[hot],
                T[hot],
            )

            def at(d: F64) -> F64:
                k = np.maximum(1.0, d / cap)
                return miss_probability(net + exe * k, np.sqrt((exe_sd * k) ** 2 + net_sd**2), th)

            q[hot] = self._expect(at, m[hot], sd[hot], self.use[hot], peak[hot])
        return np.where(self.valid, q, 0.0)

    def migrations(self) -> F64:
        """Extension: instances placed away from the node they run on now (``Problem.current``;
        a re-plan's moves as a cost in the objective, not only the migration margin)."""
        cur = self.problem.current[None, :]
        moved: F64 = ((cur >= 0) & self.valid & (self.x != cur)).sum(axis=1).astype(np.float64)
        return moved

    def miss_rate(self) -> F64:
        """The fleet's miss rate (P,), one definition for the planner, the simulator, status
        and the benchmarks: the mean over modules of each module's rate, a module's rate being
        the activation-weighted mean of its placed instances' miss probabilities (the share
        of its cycles that miss). Every module counts alike, however many instances it has or
        however fast its loop, so one module missing badly cannot hide behind fast loops."""
        weight = self.module_activation
        missed = self.per_module(self.placed_activation * self.instance_miss())
        counted = weight > 0
        rate = np.where(counted, missed / np.where(counted, weight, 1.0), 0.0)
        n = counted.sum(axis=1)
        return np.asarray(
            np.where(n > 0, rate.sum(axis=1) / np.maximum(n, 1), 0.0), dtype=np.float64
        )

    def cost(self) -> F64:
        return np.asarray(self.cpu_requested @ self.problem.cost, dtype=np.float64)

    def energy(self) -> F64:
        pw = self.problem.power[self.robots]
        watts = pw[None, :, 1] + pw[None, :, 2] * self.cpu_expected[:, self.robots]
        watts = watts + pw[None, :, 3] * self.offboard_traffic[:, self.robots] / MBPS
        return np.asarray(watts.sum(axis=1), dtype=np.float64)

    def node_constraints(self) -> F64:
        """The per-node and per-robot columns of ``constraints`` (all but geneSpace)."""
        cap = self.problem.capacity
        g_cpu = (self.cpu_requested - cap[None, :, 0]) / cap[None, :, 0]
        g_mem = (self.mem_requested - cap[None, :, 1]) / np.maximum(cap[None, :, 1], 1.0)
        g_gpu = (self.gpu_requested - cap[None, :, 2]) / np.maximum(cap[None, :, 2], 1.0)
        limit = UPLINK_SHARE * self.problem.uplink_bandwidth[self.robots]
        g_up = (self.offboard_traffic[:, self.robots] - limit[None, :]) / limit[None, :]
        return np.concatenate([g_cpu, g_mem, g_gpu, g_up], axis=1)

    def constraints(self) -> F64:
        """G <= 0 feasible; each column normalised by its limit (see ``constraint_names``)."""
        outside = self.valid & ~self.problem.allowed[self._rows, self.x]
        g_gene = outside.sum(axis=1, keepdims=True).astype(np.float64)
        return np.concatenate([self.node_constraints(), g_gene], axis=1)


# Per-node sums (cached properties of Evaluation) from which the per-node objectives follow.
NODE_SUMS = (
    "cpu_requested",
    "mem_requested",
    "gpu_requested",
    "cpu_expected",
    "cpu_onboard",
    "offboard_traffic",
)
