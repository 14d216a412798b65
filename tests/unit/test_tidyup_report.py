"""The tidy-up report: the behavior's record beside the judge's verdict, the table, the
benchmark's summary over trials."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.sim.scenarios import get_scenario
from quadmanip.testbench.bench_tidyup import summarize, trial_names
from quadmanip.tidyup import TidyReport, TidyRun

pytestmark = pytest.mark.unit


def _judge(names: list[str], placed: list[str], valid: bool = True) -> m.JudgeReport:
    return m.JudgeReport(
        stamp=100.0,
        trial_time=100.0,
        in_place=placed,
        misplaced=[n for n in names if n not in placed],
        total=len(names),
        objects=names,
        locations=["in_place" if n in placed else "floor" for n in names],
        notes=["" if n in placed else "not in any place" for n in names],
        positions=np.zeros((len(names), 3)),
        rest_s=np.ones(len(names)),
        valid=valid,
    )


def _scored(judge: m.JudgeReport, progress: object) -> TidyReport:
    scn = get_scenario("short-0")  # spoon (floor), bowl (table)
    run = TidyRun(scn, log=None)  # type: ignore[arg-type]
    run.report.sim_time_s = 90.0
    run._score(progress, judge)
    return run.report


def _progress(**kw: object) -> SimpleNamespace:
    base = {
        "objects": ["spoon", "bowl"],
        "object_grasped": [True, True],
        "object_placed": [True, False],
        "object_time_s": [40.0, float("nan")],
        "object_failures": ["", "grasp: lateral_out_of_range\nplace: too far"],
        "object_positions": np.array([[2.28, 0.78, 0.0], [2.89, 3.53, 0.4]]),
        "drawers_opened": ["drawer_left", "drawer_right", "drawer_top"],
    }
    base.update(kw)
    return SimpleNamespace(**base)


def test_the_judge_decides_placed_not_the_robots_belief():
    rep = _scored(_judge(["spoon", "bowl"], ["bowl"]), _progress())
    by = {o.name: o for o in rep.objects}
    # the robot believed the spoon placed; the judge did not see it there
    assert by["spoon"].placed_by_robot and not by["spoon"].placed
    assert by["bowl"].placed and not by["bowl"].placed_by_robot
    assert by["bowl"].failures == ["grasp: lateral_out_of_range", "place: too far"]
    assert by["spoon"].where == "floor" and by["spoon"].judge_note == "not in any place"
    assert rep.placed == 1 and rep.drawers_opened == ["drawer_left", "drawer_right", "drawer_top"]
    s = rep.summary()
    assert s["objects"] == 2 and s["success_rate"] == 0.5
    assert s["sim_time_per_placed_object_s"] == 90.0


def test_an_invalid_trial_scores_nothing():
    rep = _scored(_judge(["spoon", "bowl"], ["spoon", "bowl"], valid=False), _progress())
    assert rep.placed == 0 and not rep.judge_valid


def test_objects_the_robot_never_found_are_reported():
    rep = _scored(
        _judge(["spoon", "bowl"], []),
        _progress(
            objects=[], object_grasped=[], object_placed=[], object_time_s=[], object_failures=[]
        ),
    )
    assert [o.found for o in rep.objects] == [False, False]
    table = rep.table()
    assert "spoon" in table and "bowl" in table and "placed 0 of 2" in table


def test_summary_over_trials():
    a = _scored(_judge(["spoon", "bowl"], ["spoon", "bowl"]), _progress()).to_json()
    b = _scored(_judge(["spoon", "bowl"], ["spoon"]), _progress(drawers_opened=["drawer_left"]))
    b = b.to_json()
    a["scenario"], b["scenario"] = "paper-1", "seed-3"
    s = summarize([a, b])
    assert s["objects"] == 4 and s["placed"] == 3 and s["success_rate"] == 0.75
    assert s["paper_placed"] == 2 and s["paper_objects"] == 2
    assert s["drawers_opened_min"] == 1
    # 90 s trials: 45 s per object with two placed, 90 s with one -> median 67.5
    assert s["time_per_object_s_p50"] == pytest.approx(67.5)
    assert s["falls"] == 0 and s["safety_trips"] == 0
    b["falls"], b["controller"] = 1, {"trips": 3}
    s = summarize([a, b])
    assert s["falls"] == 1 and s["safety_trips"] == 3


def test_one_class_seen_twice_counts_once():
    p = _progress(
        objects=["spoon", "spoon", "bowl"],
        object_grasped=[False, True, True],
        object_placed=[False, True, True],
        object_time_s=[5.0, 40.0, 30.0],
        object_failures=["grasp: no_object", "", ""],
        object_positions=np.array([[2.28, 0.78, 0.0], [2.3, 0.8, 0.0], [2.89, 3.53, 0.4]]),
    )
    rep = _scored(_judge(["spoon", "bowl"], ["spoon", "bowl"]), p)
    spoon = next(o for o in rep.objects if o.name == "spoon")
    assert spoon.grasped and spoon.placed_by_robot and spoon.time_s == 45.0
    assert spoon.failures == ["grasp: no_object"]
    # both records stay visible: a second one is a twin track, and what it cost
    assert spoon.records == [
        {"xy": [2.28, 0.78], "time_s": 5.0, "placed": False},
        {"xy": [2.3, 0.8], "time_s": 40.0, "placed": True},
    ]


def test_a_misclassified_object_is_matched_by_where_it_was_first_seen():
    # short-0's spoon starts at (2.28, 0.78): the robot called it a marker and placed it
    p = _progress(
        objects=["marker", "bowl"],
        object_positions=np.array([[2.30, 0.75, 0.0], [2.89, 3.53, 0.4]]),
    )
    rep = _scored(_judge(["spoon", "bowl"], ["spoon"]), p)
    spoon = next(o for o in rep.objects if o.name == "spoon")
    assert spoon.found and spoon.placed_by_robot and spoon.placed
    assert spoon.seen_as == ["marker"]
    far = _progress(
        objects=["marker", "bowl"], object_positions=np.array([[3.5, 2.0, 0.0], [2.89, 3.53, 0.4]])
    )
    assert not _scored(_judge(["spoon", "bowl"], []), far).objects[0].found


def test_command_line_faults_and_overrides():
    from quadmanip.tidyup import parse_faults, service_overrides

    assert parse_faults(["locomotion@90", "perception@12.5"]) == [
        ("locomotion", 90.0),
        ("perception", 12.5),
    ]
    for bad in ("sim@10", "locomotion", "locomotion@-1", "navigation@soon"):
        with pytest.raises(ValueError, match="SERVICE@SECONDS"):
            parse_faults([bad])
    assert service_overrides(["behavior.drawers.places=[]", "sim.sensors.lidar.rate=5"]) == {
        "behavior": ["--set", "drawers.places=[]"],
        "sim": ["--set", "sensors.lidar.rate=5"],
    }
    with pytest.raises(ValueError, match="SERVICE.KEY=VALUE"):
        service_overrides(["router.x=1"])


def test_a_false_detection_of_the_class_elsewhere_is_not_the_object():
    # a "bowl" seen in the kitchen (6.0, 3.4) is not short-0's bowl on the living table
    p = _progress(
        objects=["spoon", "bowl"], object_positions=np.array([[2.28, 0.78, 0.0], [6.0, 3.4, 0.4]])
    )
    rep = _scored(_judge(["spoon", "bowl"], ["spoon"]), p)
    assert [o.found for o in rep.objects] == [True, False]


def test_localisation_error_compares_the_map_pose_with_the_truth_of_its_instant():
    from quadmanip.tidyup import _localisation_error, _spread

    truth = [(10.00, 1.0, 2.0), (10.02, 1.01, 2.0), (10.04, 1.02, 2.0)]  # 50 Hz, walking
    pose = m.MapPose(stamp=10.02, x=1.04, y=2.04, yaw=0.0, covariance=np.eye(3), status="localized")
    assert _localisation_error(truth, pose) == pytest.approx(0.05)  # the 10.02 truth
    late = m.MapPose(stamp=10.10, x=1.04, y=2.03, yaw=0.0, covariance=np.eye(3), status="localized")
    assert _localisation_error(truth, late) is None  # no truth of that instant
    lost = m.MapPose(stamp=10.02, x=1.04, y=2.03, yaw=0.0, covariance=np.eye(3), status="lost")
    assert _localisation_error(truth, lost) is None
    s = _spread([0.01, 0.02, 0.03, 0.10])
    assert s["p50"] == pytest.approx(0.025) and s["max"] == 0.1 and s["samples"] == 4
    assert _spread([]) == {}


def test_the_controllers_deadline_counters_are_reported():
    # realtime mode: the sim does not wait for a late controller; the report says from
    # locomotion's own counters whether it kept up
    from quadmanip.tidyup import _controller

    assert _controller(None) == {}
    h = m.LocomotionHealth(
        stamp=5.0,
        state="degraded",
        reason="late answers",
        missed_ticks=3,
        late_answers=41,
        mpc_overruns=7,
        answer_ms_p99=4.25,
        leg_timeouts=0,
        cmd_age_ticks=1.5,
        degraded_episodes=2,
    )
    c = _controller(h)
    assert (c["missed_ticks"], c["late_answers"], c["mpc_overruns"]) == (3, 41, 7)
    assert c["degraded_episodes"] == 2 and c["answer_ms_p99_last_window"] == 4.25
    rep = _scored(_judge(["spoon", "bowl"], ["spoon"]), _progress())
    rep.controller = c
    assert "3 ticks missed, 41 answers late, 7 MPC overruns, 2 degraded episodes" in rep.table()
    assert rep.to_json()["controller"]["late_answers"] == 41


def test_records_of_no_scenario_object_are_reported_as_what_was_not_there():
    # a "sugar box" chased in the kitchen, where the scene has none (paper-4, paper-5)
    prog = _progress(
        objects=["spoon", "bowl", "sugar_box"],
        object_grasped=[True, True, False],
        object_placed=[True, False, False],
        object_time_s=[40.0, float("nan"), float("nan")],
        object_failures=["", "grasp: lateral_out_of_range", "probe: not in view\nprobe: again"],
        object_positions=np.array([[2.28, 0.78, 0.0], [2.89, 3.53, 0.4], [8.3, 3.1, 0.0]]),
    )
    rep = _scored(_judge(["spoon", "bowl"], ["spoon"]), prog)
    assert [u["label"] for u in rep.unmatched] == ["sugar_box"]
    assert rep.unmatched[0]["first_seen_xy"] == [8.3, 3.1]
    assert rep.unmatched[0]["failures"] == ["probe: not in view", "probe: again"]
    assert "went after what is not in the scene (1): sugar_box at (8.3, 3.1)" in rep.table()
    assert rep.to_json()["unmatched"][0]["label"] == "sugar_box"
    # the objects' own records are not among them
    rep = _scored(_judge(["spoon", "bowl"], ["spoon"]), _progress())
    assert rep.unmatched == []


def test_the_benchmark_runs_the_seeds_alone_when_only_seeds_are_given() -> None:
    assert trial_names(None, [101, 7]) == ["seed-101", "seed-7"]
    assert trial_names(None, []) == [f"paper-{i}" for i in range(1, 6)]
    assert trial_names(["paper-3"], [5]) == ["paper-3", "seed-5"]
    assert trial_names([], []) == []


def test_an_object_that_leaves_its_place_says_when_and_during_which_step():
    from quadmanip.tidyup import PlaceWatch

    def judge(stamp: float, where: list[str]) -> m.JudgeReport:
        names = ["spoon", "bowl"]
        placed = [n for n, w in zip(names, where, strict=True) if w == "in_place"]
        return dataclasses.replace(_judge(names, placed), stamp=stamp, locations=where)

    watch = PlaceWatch()
    watch.update(judge(1.0, ["floor", "floor"]), "search: living_floor", 1.0)
    watch.update(judge(2.0, ["in_place", "floor"]), "verify: spoon#3", 2.0)
    watch.update(judge(2.0, ["floor", "floor"]), "place: bowl#4", 2.5)  # a repeat: skipped
    watch.update(judge(3.0, ["in_place", "held"]), "grasp: bowl#4", 3.0)
    watch.update(judge(4.0, ["floor", "held"]), "place: bowl#4", 4.0)
    assert watch.events == {"spoon": ["left at 4.0 s during 'place: bowl#4': floor"]}
    run = TidyRun(get_scenario("short-0"), log=None)  # type: ignore[arg-type]
    run.place_watch = watch
    run._score(_progress(), _judge(["spoon", "bowl"], []))
    by = {o.name: o for o in run.report.objects}
    assert by["spoon"].left_place == watch.events["spoon"] and by["bowl"].left_place == []
    assert "in place, then left at 4.0 s during 'place: bowl#4'" in run.report.table()
    # rocking in and out of the judge's "at rest": the first ones, then a sum
    for k in range(4):
        watch.update(judge(5.0 + 2 * k, ["in_place", "held"]), "look", 5.0 + 2 * k)
        watch.update(judge(6.0 + 2 * k, ["elsewhere", "held"]), "look", 6.0 + 2 * k)
    assert watch.events["spoon"] == [
        "left at 4.0 s during 'place: bowl#4': floor",
        "left at 6.0 s during 'look': elsewhere",
        "3 more times, the last left at 12.0 s during 'look': elsewhere",
    ]


def test_the_drawers_openings_come_from_the_handles_ground_truth():
    from quadmanip.tidyup import drawer_openings

    def handles(top_x: float) -> m.GroundTruthPoses:
        return m.GroundTruthPoses(
            stamp=0.0,
            names=["left", "top"],
            positions=np.array([[9.46, 1.33, 0.14], [top_x, 1.5, 0.345]]),
            orientations=np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)),
        )

    got = drawer_openings(handles(9.46), handles(9.26))
    assert got == {"left": 0.0, "top": pytest.approx(0.2)}
    assert drawer_openings(None, handles(9.26)) == {}
    rep = TidyReport("seed-1", 1, "lockstep", drawer_openings=got)
    assert "top 0.20 m" in rep.table()
