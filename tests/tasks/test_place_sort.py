"""tasks.place and tasks.sort: zones, spots, rules, and on the lockstep simulation judged by
the simulator's truth (where the bottle stands, upright, what else moved); Stop during a sort.

The tag and liquid stages are off and the object stage runs at 5 Hz: the tests spend their
time rendering, and neither stage matters here (the sort measures with the analyze task's
own meter).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from armvision.bench.system import sim_system
from armvision.config import Config, load_config
from armvision.errors import ConfigError
from armvision.geometry import make_T, rpy_to_R
from armvision.perception.liquid import LiquidLevelMeter
from armvision.robot.kinematics import VX300S, fk, ik
from armvision.runtime.context import TaskError, TaskStopped
from armvision.runtime.planning_scene import Body, PlanningScene
from armvision.sim.scene import (
    SORT_FILL_MARGIN,
    ObjectSpec,
    SceneSpec,
    generate_scene,
    random_camera_pose,
)
from armvision.tasks.analyze import AnalyzeResult
from armvision.tasks.carry import Held, held_body_clearance
from armvision.tasks.grab import grab
from armvision.tasks.place import (
    place,
    plan_set_down,
    spot_refusal,
    zone_candidates,
    zone_spot,
)
from armvision.tasks.sort import SortRule, aside_candidates, in_zone, sort

BOTTLE = ObjectSpec("bottle", "bottle", 0.030, 0.20, 0.7, "juice", x=0.40, y=0.05, yaw=0.4)
CUP = ObjectSpec("cup", "cup", 0.034, 0.10, 0.3, "water", x=0.36, y=-0.10)


def _config(**sections: object) -> Config:
    config = Config()
    runtime = dataclasses.replace(
        config.runtime, tag_detection=False, liquid_detection=False, object_hz=5.0
    )
    grab_cfg = dataclasses.replace(config.grab, track_wait_s=3.0)
    return dataclasses.replace(config, runtime=runtime, grab=grab_cfg, **sections)


def _scene(*objects: ObjectSpec) -> SceneSpec:
    return SceneSpec(random_camera_pose(Config().sim, None), objects)


HELD = Held(0.03, 0.2, 0.0, 0.09, 0.33, np.array([0.4, 0.0]))


# --------------------------------------------------------------------------- configuration


def test_zones_are_validated_with_one_line_errors(tmp_path) -> None:
    bad = tmp_path / "small.toml"
    bad.write_text("[place.zones]\nempty = [0.3, 0.1, 0.32, 0.4]\n")
    with pytest.raises(ConfigError, match=r"zone .empty. must be .* at least 0.08 m") as info:
        load_config(bad)
    assert "\n" not in str(info.value)
    missing = tmp_path / "missing.toml"
    missing.write_text('[sort]\nbelow = "bin"\n')
    with pytest.raises(ConfigError, match=r"'sort.below' names zone .bin.*zones: empty, full"):
        load_config(missing)


def test_default_zones_lie_on_the_table_apart_from_the_sort_scenes() -> None:
    config = dataclasses.replace(Config(), sim=dataclasses.replace(Config().sim, profile="sort"))
    assert set(config.place.zones) == {"empty", "full"}
    for seed in range(12):
        scene = generate_scene(config, seed)
        bottles = [o for o in scene.objects if o.label == "bottle"]
        assert 2 <= len(bottles) <= 4
        fills = [o.fill for o in bottles]
        assert min(fills) < config.sort.fill_threshold < max(fills)  # both zones used
        assert all(abs(f - config.sort.fill_threshold) >= SORT_FILL_MARGIN - 1e-9 for f in fills)
        assert all(o.fill_visible for o in bottles)
        for o in scene.objects:
            assert in_zone(config, np.array([o.x, o.y])) is None


# --------------------------------------------------------------------------- spots


def test_a_spot_is_refused_off_the_table_taken_or_too_near_the_base() -> None:
    cup = Body((0.30, 0.30), 0.035, 0.0, 0.1, "cup", 4)
    args = ([cup], 0.03, 0.05, VX300S)
    assert "off the table" in spot_refusal(np.array([0.9, 0.0]), HELD, *args)
    assert "too near the base" in spot_refusal(np.array([0.05, 0.0]), HELD, *args)
    assert "taken: the cup (track 4)" in spot_refusal(np.array([0.31, 0.28]), HELD, *args)
    assert spot_refusal(np.array([0.30, -0.30]), HELD, *args) is None


def test_a_zone_spot_is_inside_the_zone_and_clear_of_what_stands_there() -> None:
    rect = Config().place.zones["full"]
    first = zone_spot(rect, HELD, [], 0.03, 0.05, VX300S)
    assert first is not None
    taken = Body((float(first[0]), float(first[1])), 0.035, 0.0, 0.2, "bottle", 9)
    second = zone_spot(rect, HELD, [taken], 0.03, 0.05, VX300S)
    assert second is not None
    for xy in (first, second):
        assert rect[0] + HELD.radius - 1e-9 <= xy[0] <= rect[2] - HELD.radius + 1e-9
        assert rect[1] + HELD.radius - 1e-9 <= xy[1] <= rect[3] - HELD.radius + 1e-9
    assert np.linalg.norm(second - first) >= 2 * 0.03 + 0.03
    # A zone too small for the bottle has no candidate at all.
    assert len(zone_candidates((0.2, 0.2, 0.25, 0.25), 0.03)) == 0


@pytest.mark.parametrize("zone", ["empty", "full"])
def test_each_default_zone_holds_three_of_the_widest_sort_bottles(zone: str) -> None:
    # A sort scene sends up to three bottles to one zone (the first two fills go either side
    # of the threshold). Filled one after the other, the default zone takes three of the
    # widest (radius 3.7 cm, tracked 4 mm wider by the planning scene's margin), each spot
    # inside it, 3 cm clear of the others and reachable.
    rect = Config().place.zones[zone]
    held = dataclasses.replace(HELD, radius=0.037)
    taken: list[Body] = []
    for k in range(3):
        spot = zone_spot(rect, held, taken, 0.03, 0.05, VX300S)
        assert spot is not None, f"no room for bottle {k + 1}"
        assert rect[0] + 0.037 - 1e-9 <= spot[0] <= rect[2] - 0.037 + 1e-9
        assert rect[1] + 0.037 - 1e-9 <= spot[1] <= rect[3] - 0.037 + 1e-9
        for body in taken:
            assert math.dist(spot, body.xy) >= 0.037 + body.radius + 0.03 - 1e-9
        taken.append(Body((float(spot[0]), float(spot[1])), 0.041, 0.0, 0.24, "bottle", k))


# --------------------------------------------------------------------------- sort rules


def _measured(fill: float | None, colour: str | None = None) -> AnalyzeResult:
    return AnalyzeResult(ok=True, reason="", fill=fill, colour_name=colour)


def test_the_held_bottles_clearance_is_that_of_two_vertical_cylinders() -> None:
    # Held from above at (0.4, 0, 0.25), 18 cm above its bottom: the bottle spans z 0.07 to
    # 0.27 about (0.4, 0), radius 3 cm. A canister beside it (axes 10 cm apart, overlapping
    # in height): 10 - 3 - 4 = 3 cm; a low can (its top 2 cm under the bottle's bottom, its
    # side 4 cm off): hypot(4, 2) cm. Shallow, held 2 cm ahead along the gripper's heading
    # (level, facing +x): the bottle's axis is at x = 0.42.
    q, ok = ik(make_T(rpy_to_R(0.0, math.pi / 2, 0.0), [0.4, 0.0, 0.25]), VX300S.home, VX300S)
    assert ok
    held = Held(0.03, 0.2, 0.0, 0.18, 0.4, np.array([0.4, 0.0]), from_above=True)
    canister = Body((0.4, 0.1), 0.04, 0.0, 0.19, "other", 3)
    can = Body((0.5, 0.0), 0.03, 0.0, 0.05, "other", 4)
    d, what = held_body_clearance([q], held, [can, canister], VX300S)
    assert d == pytest.approx(0.03, abs=1e-6) and "track 3" in what
    d, what = held_body_clearance([q], held, [can], VX300S)
    assert d == pytest.approx(math.hypot(0.04, 0.02), abs=1e-6) and "track 4" in what
    q, ok = ik(make_T(np.eye(3), [0.4, 0.0, 0.25]), VX300S.home, VX300S)
    assert ok
    shallow = dataclasses.replace(held, ahead=0.02, from_above=False)
    d, _ = held_body_clearance([q], shallow, [canister], VX300S)
    assert d == pytest.approx(math.hypot(0.02, 0.1) - 0.07, abs=1e-6)
    assert held_body_clearance([q], held, [], VX300S)[0] == math.inf


def test_a_bottle_held_between_tall_neighbours_is_slid_back_not_lifted_over_them() -> None:
    # Taken from above from between two 19 cm canisters 1.5 cm away and lifted 10 cm, the
    # bottle's spot (tracked 1.5 cm off the grip) is reached by sliding it back at that
    # height; lifted over the canisters first, as any set-down is, it would be out of reach.
    held = Held(0.03, 0.2, 0.0, 0.18, 0.41, np.array([0.40, 0.0]), from_above=True)
    T = make_T(rpy_to_R(0.0, math.pi / 2, 0.0), [0.415, 0.0, 0.28])
    q, ok = ik(T, VX300S.home, VX300S)
    assert ok
    canisters = tuple(
        Body((0.40, y), 0.04, 0.0, 0.19, "other", k) for k, y in enumerate((0.085, -0.085), 1)
    )
    scene = PlanningScene(0.0, canisters, ())
    spot = np.array([0.40, 0.0])
    lifted = plan_set_down(q, T, spot, held, scene, 0.03, VX300S)
    assert isinstance(lifted, str)
    slid = plan_set_down(q, T, spot, held, scene, 0.03, VX300S, low=True)
    assert not isinstance(slid, str), slid
    for qs in (slid.carry, slid.lower):
        d, _ = held_body_clearance(qs, held, canisters, VX300S)
        assert d >= 0.0149 - 0.002  # 1.5 cm where it was taken, never 2 mm nearer
    final = np.asarray(slid.lower[-1])
    assert np.allclose(fk(final, VX300S)[:2, 3], spot, atol=1e-3)
    # Stop, consulted before each option, ends the planning at once.
    asked = []

    def stop() -> None:
        asked.append(1)
        raise TaskStopped("stopped")

    with pytest.raises(TaskStopped):
        plan_set_down(q, T, spot, held, scene, 0.03, VX300S, low=True, stop=stop)
    assert len(asked) == 1


def test_aside_spots_ring_the_bottle_nearest_first_and_nearest_the_base_first() -> None:
    spots = aside_candidates(np.array([0.4, 0.1]))
    d = np.linalg.norm(spots - [0.4, 0.1], axis=1)
    assert len(spots) == 48 and np.all(np.diff(np.round(d, 9)) >= 0)
    assert np.allclose(sorted(set(np.round(d, 9))), [0.1, 0.13, 0.16])
    first_ring = np.linalg.norm(spots[:16], axis=1)
    assert np.all(np.diff(first_ring) >= -1e-12)
    assert np.linalg.norm(spots[0]) == pytest.approx(math.hypot(0.4, 0.1) - 0.1, abs=0.01)


def test_the_sort_looks_again_for_bottles_uncovered_by_those_retried() -> None:
    # A hand-worked run of the sort's loop (the grasps faked): bottle 1 is refused and waits,
    # bottle 2 is placed; with no bottle left the sort looks again after a pause, then tries
    # bottle 1 again, which is placed and uncovers bottle 3 behind it (in a cluttered sort
    # scene such a bottle was never sorted); bottle 3 is sorted, and the sort ends when
    # looking again and the retries find nothing new.
    from types import SimpleNamespace

    from armvision.tasks import sort as sort_module

    config = _config()
    sleeps: list[float] = []
    ctx = SimpleNamespace(
        config=config,
        now=lambda: 0.0,
        progress=lambda *_: None,
        sleep=sleeps.append,
        wait_until=lambda *_: True,
        state=lambda: SimpleNamespace(bottles=lambda: [1]),
    )
    run = sort_module._Sort(ctx, SortRule("fill"))
    tracks = {k: SimpleNamespace(id=k, p_base=np.array([0.3, 0.1 * k, 0.1])) for k in (1, 2, 3)}
    visible = [1, 2]

    def next_bottle():
        seen = {r.track_id for r in run.reports}
        return next((tracks[k] for k in visible if k not in seen), None)

    def handle(track, report):
        if track.id == 1:
            run.wait(report, "full", "fill 70 %")
        else:
            report.action = "placed"

    def retry_waiting():
        for waiting in list(run.waiting):
            run.waiting.remove(waiting)
            waiting.report.action, waiting.report.tries = "placed", 2
            visible.append(3)  # bottle 1 stood in front of it
        return True

    run.next_bottle, run.handle, run.retry_waiting = next_bottle, handle, retry_waiting
    result = run.run()
    assert [(b.track_id, b.action, b.tries) for b in result.bottles] == [
        (1, "placed", 2),
        (2, "placed", 1),
        (3, "placed", 1),
    ]
    # The settle before the first bottle, then a look again each time none was left.
    assert sleeps == [sort_module.SETTLE_S] * 3


def test_the_fill_rule_chooses_below_or_above_the_threshold() -> None:
    rule = SortRule.make(Config(), "fill", None)
    assert rule.zone_for(_measured(0.12))[0] == "empty"
    assert rule.zone_for(_measured(0.30))[0] == "full"
    assert rule.zone_for(_measured(None)) == (None, "unknown fill")
    strict = SortRule.make(Config(), "fill", {"threshold": 0.5})
    assert strict.zone_for(_measured(0.4))[0] == "empty"


def test_the_colour_rule_maps_names_to_zones_with_a_fallback() -> None:
    rule = SortRule.make(Config(), "colour", {"orange": "full", "*": "empty"})
    assert rule.zone_for(_measured(0.5, "orange"))[0] == "full"
    assert rule.zone_for(_measured(0.5, "dark red"))[0] == "empty"
    assert rule.zone_for(_measured(0.5, None))[0] is None
    only = SortRule.make(Config(), "colour", {"orange": "full"})
    assert only.zone_for(_measured(0.5, "blue")) == (None, "no zone for the colour 'blue'")


@pytest.mark.parametrize(
    ("by", "rule", "message"),
    [
        ("size", None, "sort by 'fill' or 'colour'"),
        ("fill", {"threshold": 1.5}, "between 0 and 1"),
        ("fill", {"threshold": "half"}, "must be a number"),
        ("fill", {"below": "bin"}, "no zone 'bin' in place.zones"),
        ("fill", {"limit": 0.3}, "keys threshold, below, above"),
        ("colour", None, "needs a rule"),
        ("colour", {"teal": "full"}, "unknown colour name 'teal'"),
        ("colour", {"orange": "bin"}, "no zone 'bin'"),
    ],
)
def test_a_bad_rule_is_a_one_line_error(by, rule, message) -> None:
    with pytest.raises(TaskError, match=message) as info:
        SortRule.make(Config(), by, rule)
    assert "\n" not in str(info.value)


# --------------------------------------------------------------------------- on the simulator


@pytest.fixture(scope="module")
def placed():
    """A grab, then a place into the zone "full", on a bottle-and-cup scene."""
    config = _config()
    system = sim_system(config, 3, scene=_scene(BOTTLE, CUP))
    system.start()
    system.pump(system.clock() + 1.5)
    start = {o.spec.name: o.T_base_obj[:3, 3].copy() for o in system.world.objects()}
    q0 = system.world.joint_positions().copy()
    refused = {
        "nothing held": system.run_task("place", place, zone="full"),
        "unknown zone": system.run_task("place", place, zone="bin"),
    }
    q_refused = system.world.joint_positions().copy()
    grabbed = system.run_task("grab", grab)
    q_held = system.world.joint_positions().copy()
    off_table = system.run_task("place", place, x=0.95, y=0.0)
    q_off = system.world.joint_positions().copy()
    status = system.run_task("place", place, zone="full")
    yield {
        "system": system,
        "start": start,
        "refused": refused,
        "moved_while_refused": float(np.max(np.abs(q_refused - q0))),
        "grabbed": grabbed,
        "off_table": off_table,
        "moved_off_table": float(np.max(np.abs(q_off - q_held))),
        "status": status,
    }
    system.close()


def test_place_without_a_held_bottle_or_with_an_unknown_zone_fails_and_nothing_moves(
    placed,
) -> None:
    nothing, unknown = placed["refused"]["nothing held"], placed["refused"]["unknown zone"]
    assert nothing.phase == "failed" and "nothing is held" in nothing.error
    assert unknown.phase == "failed" and "no zone 'bin' in place.zones" in unknown.error
    assert placed["moved_while_refused"] < 1e-3


def test_a_spot_off_the_table_is_refused_with_the_bottle_still_held(placed) -> None:
    assert placed["grabbed"].phase == "succeeded"
    off = placed["off_table"]
    assert off.phase == "failed" and "off the table" in off.error
    assert placed["moved_off_table"] < 1e-3


def test_the_bottle_is_set_down_upright_in_the_zone_near_the_asked_spot(placed) -> None:
    system, status = placed["system"], placed["status"]
    assert status.phase == "succeeded", status.error
    result = status.result
    assert result["ok"] and result["upright"] and result["zone"] == "full"
    objects = {o.spec.name: o for o in system.world.objects()}
    bottle = objects["bottle"]
    asked = np.array(result["asked"])
    assert bottle.upright and not bottle.held
    assert np.linalg.norm(bottle.T_base_obj[:2, 3] - asked) < 0.02
    assert in_zone(system.config, bottle.T_base_obj[:2, 3]) == "full"
    # Its tracked position agrees with where it truly stands, and the cup did not move.
    assert np.linalg.norm(bottle.T_base_obj[:2, 3] - np.array(result["placed"])) < 0.02
    cup = objects["cup"]
    assert np.linalg.norm(cup.T_base_obj[:3, 3] - placed["start"]["cup"]) < 0.005
    assert system.world.held_object() is None


class _StopMeter(LiquidLevelMeter):
    """The default meter; on its ``stop_after``-th measurement it presses Stop."""

    def __init__(self, stop_after: int) -> None:
        super().__init__()
        self.count, self.stop_after, self.system = 0, stop_after, None

    def measure(self, frame, box, geometry=None):
        self.count += 1
        if self.count == self.stop_after and self.system is not None:
            self.system.stop_task()
        return super().measure(frame, box, geometry)


def test_stop_during_a_sort_ends_it_at_once_and_the_arm_holds_still() -> None:
    meter = _StopMeter(stop_after=3)
    with sim_system(_config(), 3, scene=_scene(BOTTLE, CUP), liquid_meter=meter) as system:
        meter.system = system
        system.pump(system.clock() + 1.5)
        status = system.run_task("sort", sort)
        assert status.phase == "stopped"
        q_stop = system.world.joint_positions().copy()
        system.pump(system.clock() + 2.0)
        assert float(np.max(np.abs(system.world.joint_positions() - q_stop))) < 5e-3
        assert not system.arm.moving
        # Nothing moved: the stop came while the first bottle was being measured in place.
        bottle = next(o for o in system.world.objects() if o.spec.name == "bottle")
        assert math.dist(bottle.T_base_obj[:2, 3], (BOTTLE.x, BOTTLE.y)) < 0.005


def test_a_second_track_inside_the_excluded_one_is_the_same_object() -> None:
    from armvision.runtime.planning_scene import PlanningScene

    target = Body((0.40, 0.10), 0.035, 0.0, 0.2, "bottle", 1)
    twin = Body((0.385, 0.105), 0.04, 0.0, 0.2, "bottle", 7)  # 1.6 cm off: inside it
    neighbour = Body((0.40, 0.175), 0.035, 0.0, 0.2, "bottle", 2)  # 1 cm gap: a real one
    scene = PlanningScene(0.0, (target, twin, neighbour), ())
    assert [b.track_id for b in scene.obstacles(1)] == [2]
    assert [b.track_id for b in scene.obstacles(None)] == [1, 7, 2]


def _cans_around(x: float, reach: float, bearings_deg: list[float]) -> list[ObjectSpec]:
    """Cans ``reach`` m from (x, 0) at these bearings."""
    return [
        ObjectSpec(
            f"can{k}",
            "can",
            0.033,
            0.12,
            0.0,
            "water",
            x=x + reach * math.cos(a),
            y=reach * math.sin(a),
        )
        for k, a in enumerate(np.radians(bearings_deg))
    ]


def test_a_bottle_refused_for_its_neighbours_is_sorted_once_the_one_in_front_is_moved() -> None:
    # The inner bottle stands in a half ring of cans 12 cm away, the outer bottle 8 cm in
    # front of it on the base's side: every approach to the inner one is blocked (the cans'
    # side and the outer bottle's), the outer one is free. The sort looks at the inner one
    # first (the camera faces the base from beyond them), is refused, sorts the outer one and
    # then takes the inner one from the side the outer one left free.
    inner = ObjectSpec("inner", "bottle", 0.030, 0.20, 0.1, "juice", x=0.45, y=0.0)
    outer = ObjectSpec("outer", "bottle", 0.030, 0.20, 0.7, "juice", x=0.37, y=0.0)
    cans = _cans_around(0.45, 0.12, [45.0, 90.0, -45.0, -90.0])
    config = _config()
    with sim_system(config, 3, scene=_scene(inner, outer, *cans)) as system:
        system.pump(system.clock() + 1.5)
        status = system.run_task("sort", sort)
        system.pump(system.clock() + 2.0)
        objects = {o.spec.name: o for o in system.world.objects()}
        reports = status.result["bottles"]
    assert status.phase == "succeeded", status.error
    for name, zone in (("inner", "empty"), ("outer", "full")):
        assert objects[name].upright
        assert in_zone(config, objects[name].T_base_obj[:2, 3]) == zone
    for can in cans:
        assert math.dist(objects[can.name].T_base_obj[:2, 3], (can.x, can.y)) < 0.02
    first, second = reports
    assert math.dist(first["start"], (inner.x, inner.y)) < 0.02
    assert first["action"] == "placed" and first["tries"] == 2
    assert second["action"] == "placed" and second["tries"] == 1


def test_a_bottle_taken_from_above_is_set_down_upright_in_the_zone() -> None:
    # A short bottle with cans 1.5 cm from it on three sides: taken by the cap from above,
    # carried pointing down over the cans, set down in "full" and released straight up.
    target = ObjectSpec("target", "bottle", 0.030, 0.16, 0.5, "juice", x=0.34, y=0.0)
    cans = _cans_around(0.34, 0.077, [60.0, -60.0, 180.0])
    config = _config()
    with sim_system(config, 3, scene=_scene(target, *cans)) as system:
        system.pump(system.clock() + 1.5)
        grabbed = system.run_task("grab", grab)
        assert grabbed.phase == "succeeded", grabbed.error
        assert grabbed.result["from_above"]
        status = system.run_task("place", place, zone="full")
        assert status.phase == "succeeded", status.error
        system.pump(system.clock() + 2.0)
        objects = {o.spec.name: o for o in system.world.objects()}
        assert system.world.held_object() is None
    bottle = objects["target"]
    assert bottle.upright and in_zone(config, bottle.T_base_obj[:2, 3]) == "full"
    assert math.dist(bottle.T_base_obj[:2, 3], status.result["asked"]) < 0.02
    for can in cans:
        assert math.dist(objects[can.name].T_base_obj[:2, 3], (can.x, can.y)) < 0.005
        assert objects[can.name].upright


def test_a_bottle_between_two_canisters_is_set_aside_then_sorted() -> None:
    # A 20 cm bottle with a 19 cm canister 1.5 cm from it on either side (across the line
    # from the base): from the side the fingers meet a canister whatever the heading, and
    # held by the cap the bottle would have to be lifted over the canisters, higher than the
    # arm reaches pointing down. So the sort takes it from above, slides it out toward the
    # base at the height it lifted it to, sets it down, and takes it from there to its zone.
    target = ObjectSpec("target", "bottle", 0.030, 0.20, 0.7, "juice", x=0.40, y=0.0)
    canisters = [
        ObjectSpec(f"canister{k}", "canister", 0.04, 0.19, 0.0, "water", x=0.40, y=y)
        for k, y in enumerate((0.085, -0.085))
    ]
    config = _config()
    with sim_system(config, 3, scene=_scene(target, *canisters)) as system:
        system.pump(system.clock() + 1.5)
        status = system.run_task("sort", sort)
        system.pump(system.clock() + 2.0)
        objects = {o.spec.name: o for o in system.world.objects()}
        held = system.world.held_object()
    assert status.phase == "succeeded", status.error
    (report,) = status.result["bottles"]
    assert report["action"] == "placed", report["reason"]
    assert report["aside"] is not None and "set aside first" in report["reason"]
    assert abs(math.dist(report["aside"], report["start"]) - 0.1) < 1e-3  # the nearest tried
    assert held is None
    bottle = objects["target"]
    assert bottle.upright and in_zone(config, bottle.T_base_obj[:2, 3]) == "full"
    for can in canisters:
        assert math.dist(objects[can.name].T_base_obj[:2, 3], (can.x, can.y)) < 0.02
        assert objects[can.name].upright
