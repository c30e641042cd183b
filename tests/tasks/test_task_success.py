"""Each task's success predicate and reward terms as the task classes compute them, on hand-built states.

The tasks are evaluated through their public ``evaluate`` / ``on_samples`` / predicate methods with an
:class:`EpisodeMonitor` and, where the task looks at the cable, a stand-in scene holding hand-placed cable
nodes (pure: no simulation). Expected numbers are written out from the paper (eq. 4-7, tables IV and V) and
docs/TASKS.md, with the boundaries on both sides.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from dyndlo_vision.sim import CableParams
from dyndlo_vision.tasks import EpisodeMonitor, Hooking, TimeOscillation, TipControl, Vaulting
from dyndlo_vision.tasks.hooking import HOOK_PRONG
from dyndlo_vision.tasks.time_oscillation import LAYOUTS
from dyndlo_vision.tasks.vaulting import (
    OBSTACLE_CENTRE_M,
    SUPPORT_M,
    beyond_cable_reach,
    crosses_over_obstacle,
    middle_landed_beyond,
)

TERMS = ("r_avoid", "r_distance", "r_success", "r_dyn")


class _Scene:
    """The parts of :class:`dyndlo_vision.sim.Scene` the tasks' evaluations read."""

    def __init__(self, nodes: np.ndarray, tcp: np.ndarray | None = None, time: float = 0.0) -> None:
        self._nodes = np.asarray(nodes, dtype=float)
        self._tcp = np.asarray(tcp if tcp is not None else self._nodes[:1], dtype=float).reshape(-1, 3)
        n_seg = len(self._nodes) - 1
        self.config = SimpleNamespace(cable=SimpleNamespace(num_segments=n_seg, num_nodes=n_seg + 1))
        self.time = time

    def cable_nodes(self) -> np.ndarray:
        return self._nodes.copy()

    def tcp_positions(self) -> np.ndarray:
        return self._tcp.copy()


def _terms(terms: dict[str, float]) -> tuple[float, ...]:
    return tuple(terms[k] for k in TERMS)


def _monitor(
    min_goal_distance_m: float = np.inf, avoid: str | None = None, height: float = 0.6
) -> EpisodeMonitor:
    mon = EpisodeMonitor()
    mon.min_goal_distance_m = min_goal_distance_m
    mon.max_mean_height_m = height
    if avoid is not None:
        mon.avoid[avoid] = True
    return mon


# ------------------------------------------------------------------------------------------------ task I
def test_tip_control_success_radius_is_target_radius_plus_eps_goal() -> None:
    # docs/TASKS.md: within eps_goal = 1 cm (table V) of the 5 cm target's surface: 2.5 + 1 = 3.5 cm.
    assert TipControl().success_radius_m == pytest.approx(0.035, abs=1e-12)
    assert TipControl(multi_step=True).success_radius_m == pytest.approx(0.035, abs=1e-12)


@pytest.mark.parametrize(
    ("distance", "hit"), [(0.0, True), (0.0349, True), (0.0351, False), (0.045, False), (0.06, False)]
)
def test_tip_control_success_at_the_boundary(distance: float, hit: bool) -> None:
    task = TipControl()
    goal = np.array([0.8, 0.0, 0.4])
    terms, success, info = task.evaluate(None, goal, _monitor(distance), True)
    assert success is hit
    # Task I column of table V: lambda_2 = -1 (I_dist = not hit, docs/TASKS.md), lambda_3 = 10.
    assert _terms(terms) == ((0.0, 0.0, 10.0, 0.0) if hit else (0.0, -1.0, 0.0, 0.0))
    assert info["min_distance_m"] == distance


@pytest.mark.parametrize(("distance", "done"), [(0.0349, True), (0.0351, False)])
def test_tip_control_multi_step_ends_at_the_hit(distance: float, done: bool) -> None:
    task = TipControl(multi_step=True)
    goal = np.array([0.8, 0.0, 0.4])
    assert task.is_done_early(None, goal, _monitor(distance)) is done
    terms, success, _ = task.evaluate(None, goal, _monitor(distance, avoid="velocity", height=0.75), True)
    # Task I multi-step column: lambda_1 = -50, lambda_2 = -1, lambda_3 = 100, lambda_4 = -1, M = 0.75 m.
    assert success is done
    assert _terms(terms) == ((-50.0, 0.0, 100.0, -1.0) if done else (-50.0, -1.0, 0.0, -1.0))


def test_tip_control_pays_nothing_before_the_end() -> None:
    task = TipControl(multi_step=True)
    terms, success, _ = task.evaluate(None, np.zeros(3), _monitor(0.0, avoid="outreach", height=0.9), False)
    assert _terms(terms) == (0.0, 0.0, 0.0, 0.0) and not success


def test_tip_control_terms_with_avoid_and_height() -> None:
    # A miss with an avoid condition and the TCP at M: -5 - 1 + 0 - 1 = -7 (task I column).
    terms, success, _ = TipControl().evaluate(
        None, np.zeros(3), _monitor(0.2, avoid="shoulder", height=0.75), True
    )
    assert _terms(terms) == (-5.0, -1.0, 0.0, -1.0) and not success
    terms, _, _ = TipControl().evaluate(None, np.zeros(3), _monitor(0.2, height=0.7499), True)
    assert terms["r_dyn"] == 0.0


@pytest.mark.parametrize(("distance", "r_distance"), [(0.135, -1.0), (0.085, -0.5), (0.03, 0.0)])
def test_tip_control_linear_distance_reward(distance: float, r_distance: float) -> None:
    # The shaped variant: lambda_2 per 10 cm of closest approach beyond the 3.5 cm success radius.
    task = TipControl(distance_reward="linear")
    terms, _, _ = task.evaluate(None, np.zeros(3), _monitor(distance), True)
    assert terms["r_distance"] == pytest.approx(r_distance, abs=1e-12)


# ------------------------------------------------------------------------------------------------ task II
BOX_X, BOX_TOP, FAR_FACE = (
    0.55,
    0.14,
    0.57,
)  # obstacle centre x, top (0.07 + 0.14 / 2) and far face (0.55 + 0.02)


def test_vaulting_obstacle_geometry() -> None:
    assert OBSTACLE_CENTRE_M == (BOX_X, 0.0, 0.07)


@pytest.mark.parametrize(
    ("middle", "landed"),
    [
        ((0.5701, 0.0, 0.01), True),
        ((0.5699, 0.0, 0.01), False),  # not past the far face
        ((0.56, 0.0, 0.01), False),  # past the box's centre but not its far face
        ((0.65, 0.0, 0.1399), True),
        ((0.65, 0.0, 0.1401), False),  # above the box's top: held in the air
        ((0.65, 0.3, 0.01), True),  # beside, but beyond: x and z decide
        ((0.45, 0.0, 0.01), False),  # the robot's side
    ],
)
def test_vaulting_middle_landed_beyond_boundaries(middle: tuple[float, float, float], landed: bool) -> None:
    assert middle_landed_beyond(np.array(middle)) is landed


@pytest.mark.parametrize(
    ("z_before", "z_after", "over"),
    [
        # A segment from x = 0.53 to x = 0.57 crosses the mid-plane x = 0.55 halfway: its height there is the
        # mean of its ends; it must be >= top - 1 cm = 0.13 m.
        (0.1405, 0.1205, True),  # 0.1305
        (0.1395, 0.1195, False),  # 0.1295
        (0.20, 0.07, True),  # 0.135: one end below the limit, the crossing above it
        (0.20, 0.05, False),  # 0.125: one end above, the crossing below
        (0.05, 0.20, False),
        (0.15, 0.15, True),
    ],
)
def test_vaulting_crossing_height_is_interpolated_at_the_mid_plane(
    z_before: float, z_after: float, over: bool
) -> None:
    nodes = np.array([[0.40, 0.0, 0.20], [0.53, 0.0, z_before], [0.57, 0.0, z_after], [1.00, 0.0, 0.01]])
    assert crosses_over_obstacle(nodes) is over


def test_vaulting_crossing_interpolation_uses_the_x_fraction() -> None:
    # Crossing 1/4 of the way from (0.54, 0.10) to (0.58, 0.18): z = 0.10 + 0.25 * 0.08 = 0.12 < 0.13.
    nodes = np.array([[0.40, 0.0, 0.20], [0.54, 0.0, 0.10], [0.58, 0.0, 0.18], [1.00, 0.0, 0.01]])
    assert not crosses_over_obstacle(nodes)
    # 3/4 of the way from (0.52, 0.1001) to (0.56, 0.1401): z = 0.1001 + 0.75 * 0.04 = 0.1301 >= 0.13: over.
    nodes = np.array([[0.40, 0.0, 0.20], [0.52, 0.0, 0.1001], [0.56, 0.0, 0.1401], [1.00, 0.0, 0.01]])
    assert crosses_over_obstacle(nodes)


def test_vaulting_every_crossing_must_be_over_the_box() -> None:
    over = [[0.40, 0.0, 0.20], [0.53, 0.0, 0.15], [0.57, 0.0, 0.15]]
    back_low = [[0.53, 0.0, 0.02], [0.60, 0.0, 0.02]]  # back under the box's top, then out again
    assert crosses_over_obstacle(np.array(over + [[1.00, 0.0, 0.01]]))
    assert not crosses_over_obstacle(np.array(over + back_low))
    # Never reaching the mid-plane is no vault.
    assert not crosses_over_obstacle(np.array([[0.40, 0.0, 0.20], [0.54, 0.0, 0.3]]))
    assert not crosses_over_obstacle(np.array([[0.60, 0.0, 0.25], [1.00, 0.0, 0.01]]))


def _vault_nodes(middle: tuple[float, float, float], crossing_z: float) -> np.ndarray:
    """61 nodes (the 90 cm, 60-segment cable): TCP, over the mid-plane at ``crossing_z``, middle, support."""
    tcp, support = np.array([0.40, 0.0, 0.20]), np.array([1.00, 0.0, 0.01])
    a, b = np.array([0.50, 0.0, crossing_z]), np.array([0.60, 0.0, crossing_z])
    m = np.array(middle)
    parts = [
        np.linspace(tcp, a, 11)[:-1],  # nodes 0-9
        np.linspace(a, b, 11)[:-1],  # nodes 10-19, crossing x = 0.55 between nodes 14 and 15
        np.linspace(b, m, 11)[:-1],  # nodes 20-29
        np.linspace(m, support, 31),  # nodes 30 (the middle) - 60
    ]
    nodes = np.vstack(parts)
    assert nodes.shape == (61, 3) and np.allclose(nodes[30], m)
    return nodes


@pytest.mark.parametrize(
    ("middle", "crossing_z", "success"),
    [
        ((0.65, 0.0, 0.01), 0.15, True),
        ((0.65, 0.0, 0.01), 0.02, False),  # around the box (crossing at floor height)
        ((0.65, 0.0, 0.30), 0.35, False),  # middle held up over the far side
        ((0.56, 0.0, 0.01), 0.15, False),  # middle short of the far face
    ],
)
def test_vaulting_success_and_terms(
    middle: tuple[float, float, float], crossing_z: float, success: bool
) -> None:
    task = Vaulting()
    scene = _Scene(_vault_nodes(middle, crossing_z))
    assert task.p_dlo_node(scene) == 30
    assert task.landed_beyond(scene) is success
    terms, ok, info = task.evaluate(scene, np.array(OBSTACLE_CENTRE_M), _monitor(height=0.25), True)
    assert ok is success
    # Vaulting column of table V: lambda_2 = -1, lambda_3 = 10; M = 0.3 m not reached (0.25 m).
    assert _terms(terms) == ((0.0, 0.0, 10.0, 0.0) if success else (0.0, -1.0, 0.0, 0.0))
    assert info["middle_x_m"] == pytest.approx(middle[0])


def test_vaulting_avoid_and_height_terms() -> None:
    task = Vaulting()
    scene = _Scene(_vault_nodes((0.65, 0.0, 0.01), 0.15))
    terms, ok, _ = task.evaluate(scene, np.zeros(3), _monitor(avoid="outreach", height=0.30), True)
    # lambda_1 = -10, lambda_4 = -2 at z_P = M = 0.3 m (>=); the success itself still pays 10.
    assert ok and _terms(terms) == (-10.0, 0.0, 10.0, -2.0)
    terms, ok, _ = task.evaluate(scene, np.zeros(3), _monitor(height=0.2999), False)
    assert not ok and _terms(terms) == (0.0, 0.0, 0.0, 0.0)  # nothing before the end


@pytest.mark.parametrize(("length", "distance", "torn"),
                         [(0.9, 0.899, False), (0.9, 0.901, True), (1.0, 0.95, False), (1.0, 1.001, True)])
def test_vaulting_tcp_beyond_the_cables_reach_from_the_support(
    length: float, distance: float, torn: bool
) -> None:
    direction = np.array([-0.6, 0.0, 0.8])  # up and back from the support, towards the robot
    tcp = np.array(SUPPORT_M) + distance * direction
    assert beyond_cable_reach(tcp, length) is torn
    # Any of K samples decides; a (K, 3) array is checked whole.
    assert beyond_cable_reach(np.vstack([np.array(SUPPORT_M) + 0.5 * direction, tcp]), length) is torn


def test_vaulting_torn_cable_is_an_avoid_that_ends_the_episode_and_is_never_a_success() -> None:
    task = Vaulting(cable=CableParams(length_m=1.0, num_segments=60))
    scene = _Scene(_vault_nodes((0.65, 0.0, 0.01), 0.15))  # a vault, as far as the cable's state shows
    mon = _monitor(height=0.25)
    direction = np.array([-0.6, 0.0, 0.8])
    samples = np.array(SUPPORT_M) + np.array([0.9, 0.99])[:, None] * direction  # within a 1.0 m cable's reach
    z3 = np.zeros((2, 1, 3))
    task.on_samples(np.array([0.0, 0.002]), samples[:, None], z3, samples, np.zeros(2), mon)
    assert mon.avoid["torn"] is False and not task.is_done_early(scene, np.zeros(3), mon)
    terms, ok, _ = task.evaluate(scene, np.zeros(3), mon, True)
    assert ok and _terms(terms) == (0.0, 0.0, 10.0, 0.0)
    beyond = np.array(SUPPORT_M) + 1.01 * direction
    task.on_samples(np.array([0.004]), beyond[None, None], z3[:1], beyond[None], np.zeros(1), mon)
    later = samples[:1]  # back within reach: the flag stays
    task.on_samples(np.array([0.006]), later[:, None], z3[:1], later, np.zeros(1), mon)
    assert mon.avoid["torn"] is True and task.is_done_early(scene, np.zeros(3), mon)
    terms, ok, _ = task.evaluate(scene, np.zeros(3), mon, True)
    assert not ok and _terms(terms) == (-10.0, -1.0, 0.0, 0.0)


def test_vaulting_ignores_cable_floor_contact_but_the_others_do_not() -> None:
    # docs/TASKS.md: the vaulting cable lies on the floor by design.
    assert Vaulting.check_collision is False
    assert TipControl.check_collision and Hooking.check_collision and TimeOscillation.check_collision


# ------------------------------------------------------------------------------------------------ task III
PRONG_A, PRONG_B = np.array(HOOK_PRONG[0]), np.array(HOOK_PRONG[1])


def test_hook_geometry() -> None:
    assert HOOK_PRONG == ((0.72, 0.0, 0.20), (0.60, 0.0, 0.23))


def _on_prong(offset_m: float, along: float = 0.5) -> np.ndarray:
    """A point ``offset_m`` from the prong's axis, perpendicular to it in the x-z plane (> 0: above)."""
    axis = PRONG_B - PRONG_A
    normal = np.array([-axis[2], 0.0, axis[0]])  # (-0.03, 0, -0.12): perpendicular, pointing down; flip it
    normal = -normal if normal[2] < 0 else normal
    normal /= np.linalg.norm(normal)
    return PRONG_A + along * axis + offset_m * normal


def _hook_nodes(k: int | None, point: np.ndarray | None = None) -> np.ndarray:
    """21 nodes (the 50 cm, 20-segment cable) hanging away from the hook, node ``k`` moved to ``point``."""
    nodes = np.column_stack([np.full(21, 0.40), np.linspace(-0.12, 0.12, 21), np.full(21, 0.05)])
    if k is not None:
        nodes[k] = point
    return nodes


@pytest.mark.parametrize(
    ("offset", "hooked"),
    [
        # Reach = prong radius 8 mm + cable radius 2 mm + 1 cm = 2 cm from the axis, above it.
        (0.0199, True),
        (0.0201, False),
        (0.005, True),
        (-0.005, False),  # below the axis: hanging under the prong, not carried by it
        (-0.015, False),
    ],
)
def test_hooking_success_distance_and_side(offset: float, hooked: bool) -> None:
    assert CableParams().radius_m == 0.002
    task = Hooking()
    assert task.hooked(_Scene(_hook_nodes(10, _on_prong(offset)))) is hooked


@pytest.mark.parametrize(
    ("k", "hooked"), [(6, False), (7, True), (10, True), (13, True), (15, False), (20, False)]
)
def test_hooking_counts_only_the_middle_third(k: int, hooked: bool) -> None:
    # 21 nodes: the middle third starts at node 7; the first 7 and the last 6 do not count.
    assert Hooking().hooked(_Scene(_hook_nodes(k, _on_prong(0.01)))) is hooked


def test_hooking_not_hooked_at_the_start_pose() -> None:
    assert not Hooking().hooked(_Scene(_hook_nodes(None)))


def test_hooking_reach_grows_with_the_cable_radius() -> None:
    # A 5 mm cable: reach 8 + 5 + 10 = 23 mm.
    task = Hooking(cable=CableParams(radius_m=0.005))
    assert task.hooked(_Scene(_hook_nodes(10, _on_prong(0.0225))))
    assert not task.hooked(_Scene(_hook_nodes(10, _on_prong(0.0235))))


@pytest.mark.parametrize("hooked", [True, False])
def test_hooking_terms(hooked: bool) -> None:
    scene = _Scene(_hook_nodes(10, _on_prong(0.01 if hooked else 0.05)))
    terms, ok, _ = Hooking().evaluate(scene, np.zeros(3), _monitor(avoid="velocity", height=0.31), True)
    # Hooking column of table V: lambda_1 = -10, lambda_2 = -1, lambda_3 = 10, lambda_4 = -2 (M = 0.3 m).
    assert ok is hooked
    assert _terms(terms) == ((-10.0, 0.0, 10.0, -2.0) if hooked else (-10.0, -1.0, 0.0, -2.0))


# ------------------------------------------------------------------------------------------------ task IV
def test_time_oscillation_layouts_keep_the_papers_distances_and_are_feasible() -> None:
    # Section V-A: the target is 0.55 m from the start (up) and 0.412 m (down).
    from dyndlo_vision.tasks.rewards import AvoidLimits, avoid_flags

    for layout, targets in LAYOUTS.items():
        for target, distance in (("up", 0.55), ("down", 0.412)):
            start, goal = (np.array(p) for p in targets[target])
            assert np.linalg.norm(goal - start) == pytest.approx(distance, abs=1e-3), (layout, target)
            task = TimeOscillation(target=target, layout=layout)
            np.testing.assert_array_equal(task.sample_goal(np.random.default_rng(0)), goal)
            np.testing.assert_array_equal(task.final_point(goal), goal)
            for p in (start, goal):  # neither end of the move breaks an avoid condition (tip 0.5 m below)
                flags = avoid_flags(p[None], np.zeros((1, 3)), p - [0, 0, 0.5], AvoidLimits())
                assert not any(flags.values()), (layout, target, p, flags)
    assert LAYOUTS["vertical"]["up"][1][2] > LAYOUTS["vertical"]["up"][0][2]  # "up" goes up
    assert LAYOUTS["vertical"]["down"][1][2] < LAYOUTS["vertical"]["down"][0][2]


def test_time_oscillation_arrival_is_the_tcps_distance_to_the_goal() -> None:
    task = TimeOscillation()
    goal = np.array(task.goal_m)
    tcp = np.array([[goal], [goal + [0.0, 0.0, -0.2]]])  # (K=2, n_g=1, 3)
    tip = tcp[:, 0] + [0.3, 0.0, -0.5]  # the tip far from the goal does not matter
    np.testing.assert_allclose(task.goal_distances(tcp, tip, goal), [0.0, 0.2], atol=1e-12)


def _run_task_iv(
    task: TimeOscillation,
    goal_dist: list[float],
    osc: list[float],
    speed: list[float] | None = None,
    t0: float = 0.0,
    period: float = 0.04,
) -> None:
    """Feed ``task.on_samples`` one sample per entry, at ``period``: TCP above the tip, tip ``osc`` aside."""
    k = len(osc)
    times = t0 + period * np.arange(k)
    start, goal = np.array(task.start_m), np.array(task.goal_m)
    frac = np.linspace(0.0, 1.0, k)[:, None]
    tcp = (start + frac * (goal - start))[:, None, :]
    vel = np.zeros_like(tcp)
    if speed is not None:
        vel[:, 0, 2] = speed
    tip = tcp[:, 0] + np.column_stack([osc, np.zeros(k), np.full(k, -0.5)])
    task.on_samples(times, tcp, vel, tip, np.asarray(goal_dist, dtype=float), EpisodeMonitor())


@pytest.mark.parametrize("target", ["up", "down"])
def test_time_oscillation_success_and_terms(target: str) -> None:
    task = TimeOscillation(target=target)
    task.begin_episode()
    # 25 Hz samples at t = 0, 0.04, ..., 0.20. Arrival (TCP within 1 cm of the goal) at the 5th, t = 0.16 s:
    # 1.01 cm does not count, 0.99 cm does.
    _run_task_iv(task, [0.5, 0.3, 0.1, 0.0101, 0.0099, 0.0], [0.0, 0.30, 0.20, 0.10, 0.03, 0.02])
    goal = np.array(task.goal_m)
    scene = _Scene(np.array([goal, goal + [0.02, 0.0, -0.5]]), tcp=goal, time=1.2)
    terms, success, info = task.evaluate(scene, goal, EpisodeMonitor(), True)
    # Per sample after arrival (docs/TASKS.md): r_success = 1.5 * 2 samples under eps_oscill = 5 cm,
    # r_dyn = -2.5 * (0.03 + 0.02) = -0.125; the 0.30 / 0.20 / 0.10 m before arrival cost nothing;
    # r_distance = lambda_2 * t_traj = -3 * 0.16 = -0.48 (eq. r_distance, explicit).
    assert _terms(terms) == pytest.approx((0.0, -0.48, 3.0, -0.125), abs=1e-12)
    assert set(terms) == set(TERMS)  # the four terms of eq. 4, nothing else
    assert success
    assert info["arrived"] and info["trajectory_time_s"] == pytest.approx(0.16)
    assert info["residual_oscillation_m"] == pytest.approx(0.03)
    assert info["oscillation_m"] == pytest.approx(0.02)


def test_time_oscillation_oscillation_before_arrival_is_not_charged() -> None:
    task = TimeOscillation()
    _run_task_iv(task, [0.5, 0.4, 0.3, 0.2], [0.25, 0.4, 0.1, 0.3])
    terms, success, info = task.evaluate(
        _Scene(np.zeros((21, 3)), time=0.5), np.zeros(3), EpisodeMonitor(), False
    )
    assert _terms(terms) == (0.0, 0.0, 0.0, 0.0)  # not arrived: no r_dyn, no r_success; r_distance at the end
    assert not success and not info["arrived"] and info["residual_oscillation_m"] == 0.0


def test_time_oscillation_residual_over_the_threshold_fails() -> None:
    task = TimeOscillation()
    _run_task_iv(task, [0.3, 0.005, 0.0, 0.0], [0.1, 0.02, 0.06, 0.01])
    terms, success, info = task.evaluate(_Scene(np.zeros((21, 3))), np.zeros(3), EpisodeMonitor(), True)
    # Arrived at t = 0.04: r_success = 1.5 * 2 (0.02, 0.01 < 0.05, not 0.06), r_dyn = -2.5 * 0.09 = -0.225,
    # r_distance = -3 * 0.04 = -0.12; max residual 6 cm >= eps_oscill: no success.
    assert _terms(terms) == pytest.approx((0.0, -0.12, 3.0, -0.225), abs=1e-12)
    assert not success and info["residual_oscillation_m"] == pytest.approx(0.06)


@pytest.mark.parametrize(("residual", "success"), [(0.0499, True), (0.0501, False)])
def test_time_oscillation_success_at_the_oscillation_threshold(residual: float, success: bool) -> None:
    # Success: arrived with the largest oscillation after arrival under eps_oscill = 0.05 m (table V).
    task = TimeOscillation()
    _run_task_iv(task, [0.2, 0.0, 0.0, 0.0], [0.3, 0.01, residual, 0.0])
    _, ok, info = task.evaluate(_Scene(np.zeros((21, 3))), np.zeros(3), EpisodeMonitor(), True)
    assert ok is success and info["residual_oscillation_m"] == pytest.approx(residual)


def test_time_oscillation_avoid_is_charged_per_sample_and_blocks_success() -> None:
    task = TimeOscillation()
    _run_task_iv(task, [0.3, 0.2, 0.0, 0.0], [0.0, 0.0, 0.01, 0.01], speed=[1.0, 1.81, 1.9, 0.0])
    monitor = EpisodeMonitor()
    monitor.avoid["velocity"] = True  # what the environment's monitor records for the same samples
    terms, success, _ = task.evaluate(_Scene(np.zeros((21, 3))), np.zeros(3), monitor, True)
    # Two samples over v_max = 1.8 m/s: r_avoid = -50 * 2 (table V, task IV); arrived at t = 0.08.
    assert _terms(terms) == pytest.approx((-100.0, -0.24, 3.0, -0.05), abs=1e-12)
    assert not success


def test_time_oscillation_never_arriving_pays_the_whole_episode_time() -> None:
    task = TimeOscillation()
    _run_task_iv(task, [0.3, 0.2, 0.1, 0.05], [0.0, 0.0, 0.0, 0.0])
    terms, success, info = task.evaluate(
        _Scene(np.zeros((21, 3)), time=5.0), np.zeros(3), EpisodeMonitor(), True
    )
    assert terms["r_distance"] == pytest.approx(-15.0)  # -3 * 5 s
    assert not success and not info["arrived"] and info["trajectory_time_s"] is None


def test_time_oscillation_is_evaluated_at_25_hz_across_calls() -> None:
    task = TimeOscillation()
    # 2 ms monitor samples over 0.1 s (t = 0 ... 0.1), arrived throughout, 1 cm oscillation, in two batches:
    # evaluated at t = 0, 0.04, 0.08 only -> r_success 3 * 1.5, r_dyn 3 * -2.5 * 0.01.
    _run_task_iv(task, [0.0] * 26, [0.01] * 26, period=0.002)
    _run_task_iv(task, [0.0] * 25, [0.01] * 25, period=0.002, t0=0.052)
    terms, _, _ = task.evaluate(_Scene(np.zeros((21, 3))), np.zeros(3), EpisodeMonitor(), False)
    assert _terms(terms) == pytest.approx((0.0, 0.0, 4.5, -0.075), abs=1e-12)


def test_time_oscillation_pending_terms_are_paid_once() -> None:
    task = TimeOscillation(multi_step=True)
    _run_task_iv(task, [0.3, 0.0], [0.0, 0.02])
    scene = _Scene(np.zeros((21, 3)), time=1.0)
    first, _, _ = task.evaluate(scene, np.zeros(3), EpisodeMonitor(), False)
    assert _terms(first) == pytest.approx((0.0, 0.0, 1.5, -0.05), abs=1e-12)
    last, success, _ = task.evaluate(scene, np.zeros(3), EpisodeMonitor(), True)
    assert _terms(last) == pytest.approx((0.0, -0.12, 0.0, 0.0), abs=1e-12)  # t_traj = 0.04 s
    assert success
    task.begin_episode()
    again, success, info = task.evaluate(scene, np.zeros(3), EpisodeMonitor(), True)
    assert not info["arrived"] and not success and again["r_distance"] == pytest.approx(-3.0)


# ---------------------------------------------------------------------------- boundaries and edges, all tasks
def test_each_task_reads_its_own_cable_node() -> None:
    """P_DLO: the tip (last node) for tasks I and IV, the middle node for tasks II and III."""
    scene = _Scene(np.zeros((31, 3)))  # 30 segments, 31 nodes
    assert TipControl().p_dlo_node(scene) == 30 and TimeOscillation().p_dlo_node(scene) == 30
    assert Vaulting().p_dlo_node(scene) == 15 and Hooking().p_dlo_node(scene) == 15


def test_tip_control_exactly_at_the_success_radius_is_a_miss() -> None:
    """Success is the closest approach strictly below D_target / 2 + eps_goal."""
    task = TipControl()
    assert task.success_radius_m == 0.025 + 0.01
    at = _monitor(min_goal_distance_m=task.success_radius_m)
    at.max_tcp_speed_m_s = 1.25
    terms, hit, info = task.evaluate(_Scene(np.zeros((21, 3))), np.zeros(3), at, True)
    assert not hit and not task.is_done_early(None, np.zeros(3), at)  # type: ignore[arg-type]
    assert info == {"min_distance_m": task.success_radius_m, "max_tcp_speed_m_s": 1.25}
    terms, _, _ = task.evaluate(_Scene(np.zeros((21, 3))), np.zeros(3), at, False)
    assert terms == {"r_avoid": 0.0, "r_distance": 0.0, "r_success": 0.0, "r_dyn": 0.0}


def test_hooking_segment_distance_hand_computed() -> None:
    from dyndlo_vision.tasks.hooking import _segment_distance

    a, b = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)
    assert _segment_distance(np.array([0.5, 0.3, 0.4]), a, b) == pytest.approx(0.5)  # beside: to the axis
    assert _segment_distance(np.array([-0.3, 0.4, 0.0]), a, b) == pytest.approx(0.5)  # before a: to a
    assert _segment_distance(np.array([1.6, 0.0, 0.8]), a, b) == pytest.approx(1.0)  # beyond b: to b


def test_hooking_above_the_prong_is_strictly_above_its_axis_and_within_its_length() -> None:
    task = Hooking()
    # At the prong's root, on its axis: not above it.
    assert not task.hooked(_Scene(_hook_nodes(10, PRONG_A.copy())))
    assert task.hooked(_Scene(_hook_nodes(10, PRONG_A + [0.0, 0.0, 1e-6])))
    # Just behind the root (x > 0.72), a hair under the root's height: under the prong, however the axis
    # would continue behind it.
    assert not task.hooked(_Scene(_hook_nodes(10, PRONG_A + [0.005, 0.0, -0.0001])))
    # Just beyond the tip (x < 0.60), a hair over the tip's height: carried at the tip.
    assert task.hooked(_Scene(_hook_nodes(10, PRONG_B + [-0.005, 0.0, 0.0005])))


def test_hooking_pays_nothing_before_the_end() -> None:
    mon = _monitor(min_goal_distance_m=0.2, avoid="velocity", height=0.5)
    terms, ok, info = Hooking().evaluate(_Scene(_hook_nodes(10, _on_prong(0.01))), np.zeros(3), mon, False)
    assert terms == {"r_avoid": 0.0, "r_distance": 0.0, "r_success": 0.0, "r_dyn": 0.0}
    assert ok is False and info == {"min_distance_m": 0.2}


def test_time_oscillation_oscillation_is_the_tips() -> None:
    task = TimeOscillation()
    goal = np.array(task.goal_m)
    nodes = np.array([goal, goal + [0.3, 0.0, -0.2], goal + [0.03, 0.04, -0.5]])  # the tip: 5 cm aside
    _, _, info = task.evaluate(_Scene(nodes, tcp=goal), goal, EpisodeMonitor(), False)
    assert info["oscillation_m"] == pytest.approx(0.05)


def test_time_oscillation_arrival_is_strictly_within_one_centimetre() -> None:
    task = TimeOscillation()
    _run_task_iv(task, [0.3, 0.01, 0.01], [0.0, 0.0, 0.0])
    _, _, info = task.evaluate(_Scene(np.zeros((21, 3))), np.zeros(3), EpisodeMonitor(), False)
    assert not info["arrived"]


def test_time_oscillation_success_needs_the_residual_strictly_under_the_threshold() -> None:
    task = TimeOscillation()
    tcp = np.zeros((3, 1, 3))
    tip = np.array([[0.3, 0.0, -0.5], [0.05, 0.0, -0.5], [0.0, 0.0, -0.5]])  # eps_oscill exactly, arrived
    task.on_samples(0.04 * np.arange(3), tcp, tcp, tip, np.array([0.2, 0.0, 0.0]), EpisodeMonitor())
    _, ok, info = task.evaluate(_Scene(np.zeros((21, 3))), np.zeros(3), EpisodeMonitor(), True)
    assert info["residual_oscillation_m"] == 0.05 and not ok


def test_time_oscillation_samples_a_hair_before_each_period_are_evaluated() -> None:
    """Monitor sample times carry rounding: one 1e-12 s before a multiple of 40 ms still counts as that
    instant (every 25 Hz instant is evaluated once)."""
    task = TimeOscillation()
    times = 0.04 * np.arange(5) - 1e-12
    times[0] = 0.0
    k = len(times)
    goal = np.array(task.goal_m)
    tcp = np.repeat(goal[None, None], k, axis=0)
    tip = tcp[:, 0] + [0.01, 0.0, -0.5]
    task.on_samples(times, tcp, np.zeros_like(tcp), tip, np.zeros(k), EpisodeMonitor())
    terms, _, _ = task.evaluate(_Scene(np.zeros((21, 3))), goal, EpisodeMonitor(), False)
    assert terms["r_success"] == pytest.approx(5 * 1.5) and terms["r_dyn"] == pytest.approx(5 * -2.5 * 0.01)


@pytest.mark.parametrize("where", ["outreach", "shoulder", "collision"])
def test_time_oscillation_charges_every_avoid_condition_per_sample(where: str) -> None:
    task = TimeOscillation()
    goal = np.array(task.goal_m)
    tcp = np.repeat(goal[None, None], 2, axis=0)
    tip = tcp[:, 0] + [0.0, 0.0, -0.5]
    if where == "outreach":
        tcp[1, 0] = [1.0, 0.0, 0.6]  # 1.06 m from the shoulder, over 0.9 m
    elif where == "shoulder":
        tcp[1, 0] = [0.1, 0.1, 1.0]  # 0.14 m from the base axis, under 0.25 m
    else:
        tip[1] = [goal[0], 0.0, 0.01]  # the tip on the floor (under 1.25 cm)
    far = np.array([0.5, 0.5])
    task.on_samples(np.array([0.0, 0.04]), tcp, np.zeros_like(tcp), tip, far, EpisodeMonitor())
    terms, _, _ = task.evaluate(_Scene(np.zeros((21, 3))), goal, EpisodeMonitor(), False)
    assert terms["r_avoid"] == pytest.approx(-50.0)  # lambda_1 of task IV, once


def test_vaulting_exact_edges_of_the_box() -> None:
    from dyndlo_vision.tasks.vaulting import OBSTACLE_SIZE_M, crossings, within_box_width

    half = OBSTACLE_SIZE_M[1] / 2
    assert within_box_width(half) and within_box_width(-half) and within_box_width(0.0)
    assert not within_box_width(half + 1e-9) and not within_box_width(-0.05)
    assert within_box_width(0.035)
    # A crossing exactly at the top less the tolerance counts as over the box.
    top = OBSTACLE_CENTRE_M[2] + OBSTACLE_SIZE_M[2] / 2
    z = top - 0.01
    nodes = np.array([[0.40, 0.0, 0.2], [0.54, 0.0, z], [0.56, 0.0, z], [1.0, 0.0, 0.01]])
    assert crosses_over_obstacle(nodes)
    # Exactly at the far face is not beyond it; exactly at the top is not below it.
    far, top_z = OBSTACLE_CENTRE_M[0] + OBSTACLE_SIZE_M[0] / 2, top
    assert not middle_landed_beyond(np.array([far, 0.0, 0.01]))
    assert not middle_landed_beyond(np.array([0.65, 0.0, top_z]))
    # The crossing's lateral position is interpolated too: 1/4 of the way from y = 0.02 to y = -0.06.
    ((y, zc),) = crossings(np.array([[0.54, 0.02, 0.2], [0.58, -0.06, 0.3]]))
    assert (y, zc) == (pytest.approx(0.0), pytest.approx(0.225))
    # Nodes exactly on the mid-plane: the crossing is there, at the first of them.
    on_plane = np.array([[0.40, 0.0, 0.2], [0.55, 0.01, 0.15], [0.55, 0.02, 0.16], [1.0, 0.0, 0.01]])
    assert crossings(on_plane)[1] == (pytest.approx(0.01), pytest.approx(0.15))
    assert crosses_over_obstacle(on_plane)


def test_vaulting_torn_is_exactly_beyond_the_cables_length() -> None:
    support = np.array(SUPPORT_M)
    assert not beyond_cable_reach(support - [0.5, 0.0, 0.0], 0.5)  # exactly the length away: reachable
    assert beyond_cable_reach(support - [0.5 + 1e-9, 0.0, 0.0], 0.5)
    assert not Vaulting().is_done_early(None, np.zeros(3), EpisodeMonitor())  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("middle_x", "crossing", "progress"),
    [
        # progress = 0.5 * reach + 0.5 * 0.999 * over; reach = (x - 0.40) / (0.57 - 0.40) in [0, 1],
        # over = lowest crossing height over the box / its top (0.14 m) in [0, 1], 0 beside the box or none.
        (0.485, (0.0, 0.07), 0.5 * 0.5 + 0.5 * 0.999 * 0.5),
        (0.30, (0.0, 0.07), 0.5 * 0.0 + 0.5 * 0.999 * 0.5),  # middle behind the TCP's home: no reach
        (0.70, (0.0, 0.28), 0.5 * 1.0 + 0.5 * 0.999 * 1.0),  # beyond the far face, high: both full
        (0.485, (0.10, 0.07), 0.5 * 0.5),  # crossing beside the box: no height
        (0.485, (0.0, -0.014), 0.5 * 0.5),  # crossing under the floor: none
        (0.485, None, 0.5 * 0.5),  # never crossing
    ],
)
def test_vault_progress_hand_computed(middle_x: float, crossing: tuple | None, progress: float) -> None:
    from dyndlo_vision.tasks.vaulting import vault_progress

    # The middle node at an end of the polyline, where it adds no crossing of its own.
    middle = [middle_x, 0.0, 0.01]
    if crossing is None:
        path = [[0.40, 0.0, 0.2], [0.50, 0.0, 0.01]]
    else:
        y, z = crossing
        path = [[0.40, 0.0, 0.2], [0.54, y, z], [0.56, y, z], [1.0, 0.0, 0.01]]
    nodes = np.array([middle, *path] if middle_x < 0.55 else [*path, middle])
    index = 0 if middle_x < 0.55 else len(nodes) - 1
    assert vault_progress(nodes, index) == pytest.approx(progress, abs=1e-12)


def test_vaulting_shaped_distance_reward_slopes_with_progress_on_failures_only() -> None:
    from dyndlo_vision.tasks.vaulting import SHAPED_DISTANCE_SCALE, vault_progress

    task = Vaulting(distance_reward="shaped")
    failed = _Scene(_vault_nodes((0.56, 0.0, 0.01), 0.07))  # middle short of the far face, crossing low
    progress = vault_progress(failed.cable_nodes(), 30)
    assert 0.3 < progress < 0.9
    terms, ok, info = task.evaluate(failed, np.zeros(3), _monitor(height=0.25), True)
    assert not ok and info["vault_progress"] == progress
    assert terms["r_distance"] == pytest.approx(-1.0 * SHAPED_DISTANCE_SCALE * (1.0 - progress))
    vault = _Scene(_vault_nodes((0.65, 0.0, 0.01), 0.15))
    terms, ok, info = task.evaluate(vault, np.zeros(3), _monitor(height=0.25), True)
    assert ok and terms["r_distance"] == 0.0 and "vault_progress" not in info
