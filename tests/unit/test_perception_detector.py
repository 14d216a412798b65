"""The detector: dataset labels, CenterNet targets and decoding, a few training iterations
(so the training code cannot rot), and the committed weights on unseen rendered scenes."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from quadmanip.services.perception import detector as det
from quadmanip.services.perception import train as tr
from quadmanip.testbench.perception_dataset import DatasetWriter, SceneRenderer, degrade_depth

WEIGHTS = det.weights_path(det.DetectorConfig().weights)


@pytest.fixture(scope="module")
def scenes() -> SceneRenderer:
    s = SceneRenderer()
    yield s
    s.close()


def test_labels_are_the_visible_pixels_and_reproducible(scenes: SceneRenderer) -> None:
    frames = scenes.render(7)
    again = scenes.render(7)
    assert [f.camera for f in frames] == ["front_camera", "gripper_camera"]
    n_labels = 0
    for f, g in zip(frames, again, strict=True):
        assert np.array_equal(f.rgb, g.rgb) and np.array_equal(f.depth, g.depth)
        for lab in f.labels:
            n_labels += 1
            x0, y0, x1, y1 = lab.box
            ys, xs = np.nonzero(lab.mask)
            assert (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1) == (x0, y0, x1, y1)
            assert lab.pixels == int(lab.mask.sum())
            assert lab.name in scenes.names
    assert n_labels >= 1  # seed 7 puts objects in view (a scene is built around them)


def test_scenes_show_the_robot_standing_as_it_searches(scenes: SceneRenderer) -> None:
    """The cameras see from where they are when the robot searches and probes: the trunk at
    the standing height (the ``home`` keyframe, 0.30 m), not the sim's start pose (lying,
    0.11 m: every frame before 2026-12-04 was rendered from 0.19 m too low), and the
    gripper camera sees the robot's own trunk between open fingers in some frames, as it
    does in the live stack, so the detector learns it is not an object."""
    from quadmanip.common import robot_description as rd

    stand = float(rd.home_qpos()[2])
    gaps = []
    for seed in range(20):
        scenes.pose_scene(seed)
        q = scenes.data.qpos
        assert stand - 0.031 <= q[scenes.free_adr + 2] <= stand + 0.011
        legs = q[scenes.leg_adr] - scenes.stand_legs
        assert np.abs(legs).max() < 0.5  # standing legs with a gait's spread
        gaps.append(float(q[scenes.finger_adr[0]]))
    lo, hi = scenes.finger_range[0]
    assert min(gaps) < lo + 0.3 * (hi - lo) and max(gaps) > lo + 0.7 * (hi - lo)


def test_tall_probe_scenes_lift_the_nose_and_stand_back(scenes: SceneRenderer) -> None:
    """``probe_tall`` frames look as the live tall-box probe does: the trunk pitched about
    the posture's body pitch, farther from the table than a table search stands, mostly a
    tall box in front; ``scene_mode`` tells a seed's mode without rendering it."""
    from quadmanip.common.rotations import quat_to_mat

    pitch0 = scenes.body_pitch["probe_tall"]
    tall = 0
    for seed in range(40000, 40400):
        if scenes.scene_mode(seed) != "probe_tall":
            continue
        mode = scenes.pose_scene(seed)
        if mode != "probe_tall":  # the stance farther back did not fit in the room
            assert mode == "probe_horizontal"
            continue
        q = scenes.data.qpos[scenes.free_adr + 3 : scenes.free_adr + 7]
        x_axis = quat_to_mat(q)[:, 0]
        pitch = -np.arcsin(np.clip(x_axis[2], -1.0, 1.0))  # nose up is negative
        assert abs(pitch - pitch0) <= 0.05 + 0.035  # the noise, and the roll's share
        x, y = scenes.data.qpos[scenes.free_adr : scenes.free_adr + 2]
        to_table = min(
            math.hypot(max(t.min[0] - x, 0.0, x - t.max[0]), max(t.min[1] - y, 0.0, y - t.max[1]))
            for t in scenes.tables
        )
        assert to_table >= 0.22 + 0.35 - 0.01  # a table search's stance plus TALL_BACK
        tall += 1
    assert tall >= 10
    modes = [scenes.scene_mode(s) for s in range(200)]
    assert modes.count("probe_tall") > 0 and modes.count("probe_horizontal") > 0


def test_depth_degradation_is_like_a_real_camera() -> None:
    rng = np.random.default_rng(0)
    d = np.full((100, 100), 2.0, np.float32)
    d[:, 50:] = 1.0  # a depth edge at column 50
    out = degrade_depth(d, rng)
    valid = out > 0
    # noise grows with distance: sigma(2 m) = 1.2 + 1.9 * 1.6^2 = 6.1 mm, sigma(1 m) 1.9 mm
    s2 = float(np.std(out[:, :40][valid[:, :40]] - 2.0))
    s1 = float(np.std(out[:, 60:][valid[:, 60:]] - 1.0))
    assert 0.004 < s2 < 0.008 and 0.0012 < s1 < 0.0027
    assert (~valid[:, 50]).mean() > 0.3  # about half the edge pixels are lost
    assert (~valid[:, 10:40]).mean() < 0.03  # speckles elsewhere


def test_targets_put_a_peak_at_the_centre_with_its_size() -> None:
    boxes = np.array([[3, 40.0, 20.0, 80.0, 44.0, 0]], np.float32)  # 40 x 24 px
    t = tr.make_targets(boxes, 5, (96, 128))
    heat = t["heat"]
    assert heat.shape == (5, 24, 32)
    cy, cx = np.unravel_index(int(np.argmax(heat[3])), heat[3].shape)
    assert (cx, cy) == (15, 8)  # centre (60, 32) px / stride 4
    assert heat[3, cy, cx] == 1.0 and heat[[0, 1, 2, 4]].max() == 0.0
    assert t["ind"][0] == cy * 32 + cx and t["mask"][0] == 1.0
    np.testing.assert_allclose(t["size"][0], [math.log(10.0), math.log(6.0)], rtol=1e-6)
    np.testing.assert_allclose(t["off"][0], [0.0, 0.0], atol=1e-6)
    ign = tr.make_targets(np.array([[1, 0, 0, 16, 16, 1]], np.float32), 5, (96, 128))
    assert ign["heat"].max() == 0.0 and ign["ignore"][:4, :4].all() and ign["mask"].sum() == 0


def test_decode_reads_back_a_box() -> None:
    heat = torch.full((1, 3, 20, 30), -9.0)
    heat[0, 2, 5, 7] = 4.0  # score sigmoid(4) = 0.982
    size = torch.zeros((1, 2, 20, 30))
    size[0, :, 5, 7] = torch.tensor([math.log(12.0), math.log(5.0)])
    off = torch.zeros((1, 2, 20, 30))
    off[0, :, 5, 7] = torch.tensor([0.25, 0.5])
    out = det.decode(heat, size, off, k=5, threshold=0.5)[0]
    assert len(out) == 1
    cls, score, box = out[0]
    assert cls == 2 and score == pytest.approx(1 / (1 + math.exp(-4.0)), rel=1e-5)
    cx, cy = (7.25) * 4, (5.5) * 4
    np.testing.assert_allclose(box, [cx - 24, cy - 10, cx + 24, cy + 10], atol=1e-4)


def test_a_second_guess_on_the_same_object_ranks_below_first_guesses() -> None:
    spoon = det.Detection("spoon", 0.8, (10.0, 10.0, 40.0, 20.0))
    marker_on_spoon = det.Detection("marker", 0.6, (11.0, 10.0, 41.0, 20.0))
    marker = det.Detection("marker", 0.5, (100.0, 50.0, 130.0, 58.0))
    spoon_elsewhere = det.Detection("spoon", 0.4, (200.0, 50.0, 230.0, 60.0))
    out = det.rank_runner_ups([marker, spoon_elsewhere, marker_on_spoon, spoon], 0.6, 0.7)
    by_box = {d.box: d for d in out}
    assert by_box[marker_on_spoon.box].score == pytest.approx(0.42)  # below the real marker
    assert by_box[marker.box].score == 0.5 and by_box[spoon.box].score == 0.8
    assert by_box[spoon_elsewhere.box].score == 0.4  # apart: not a second guess
    assert [d.score for d in out] == sorted((d.score for d in out), reverse=True)
    # nothing is dropped: a request for the marker still finds that box
    assert len(out) == 4


def test_repeat_factor_sampling_weights_frames_by_their_classes() -> None:
    data = SimpleNamespace(
        classes=("spoon", "marker", "bowl"),
        anns=[
            np.array([[0, 1, 1, 5, 5, 0]], np.float32),  # a spoon
            np.array([[2, 1, 1, 5, 5, 0], [1, 9, 9, 20, 12, 0]], np.float32),  # bowl, marker
            np.zeros((0, 6), np.float32),  # nothing
        ],
    )
    w = tr.repeat_weights(data, {"spoon": 2.0, "marker": 3.0})
    np.testing.assert_allclose(w, [2.0, 3.0, 1.0])
    assert tr.repeat_weights(data, {}) is None
    with pytest.raises(ValueError, match="no class"):
        tr.repeat_weights(data, {"fork": 2.0})
    with pytest.raises(ValueError, match=">= 1"):
        tr.repeat_weights(data, {"spoon": 0.5})


def test_a_few_training_iterations_learn_and_resume(tmp_path: Path, scenes: SceneRenderer) -> None:
    data_dir = tmp_path / "data"
    w = DatasetWriter(data_dir, scenes.names)
    for seed in range(6):
        for f in scenes.render(seed):
            if f.labels:
                w.add(f, seed)
    w.save()
    coco = json.loads((data_dir / "annotations.json").read_text())
    assert coco["images"] and coco["annotations"]
    data = tr.CocoFrames([data_dir])
    # several sets load one after the other into the arrays allocated for all of them
    twice = tr.CocoFrames([data_dir, data_dir])
    n = len(data)
    assert len(twice) == 2 * n and twice.rgb.shape == (2 * n, *data.rgb.shape[1:])
    assert np.array_equal(twice.rgb[n:], data.rgb) and np.array_equal(twice.depth[:n], data.depth)
    assert twice.seeds == data.seeds * 2
    ck, out = tmp_path / "ck.pt", tmp_path / "det.pt"
    first = tr.train(data, 4, 2, out, ck, resume=False, save_every=2, threads=1)
    assert first["iteration"] == 4 and out.exists() and ck.exists()
    losses = [v for _, v in first["history"]]
    assert all(math.isfinite(v) for v in losses)
    more = tr.train(data, 6, 2, out, ck, resume=True, save_every=2, threads=1)
    assert more["iteration"] == 6 and more["train_minutes"] >= first["train_minutes"]
    # a new cosine from the checkpoint, frames of one class drawn 3x: both recorded
    name = scenes.names[int(data.anns[0][0, 0])]
    again = tr.train(
        data, 8, 2, out, ck, resume=True, save_every=2, threads=1, restart=True, repeat={name: 3.0}
    )
    assert again["schedule_start"] == 6 and again["card"]["repeat"] == {name: 3.0}
    # batches from a worker process, the schedule fitted to a time budget: after 100
    # iterations the rate sets the end, well short of the provisional 10**6
    fitted = tr.train(
        data, 10**6, 2, out, ck, resume=True, threads=1, workers=1, budget_minutes=0.05
    )
    assert 107 <= fitted["iteration"] == fitted["card"]["iters_planned"] < 10**6
    assert fitted["schedule_start"] == 6  # a resumed part keeps the restarted cosine
    d = det.Detector(det.DetectorConfig(weights=str(out), score_threshold=0.0))
    assert d.classes == scenes.names
    found = d(scenes.render(0)[1].rgb, scenes.render(0)[1].depth)
    assert all(isinstance(x, det.Detection) for x in found)


def test_bad_input_shapes_are_refused() -> None:
    if not WEIGHTS.exists():
        pytest.skip("no committed weights")
    d = det.Detector(det.DetectorConfig())
    with pytest.raises(ValueError, match="need rgb"):
        d(np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.float32))
    # an odd size is padded, not resized: boxes stay in the image
    out = d(np.zeros((100, 150, 3), np.uint8), np.zeros((100, 150), np.float32))
    assert all(0 <= b.box[0] < b.box[2] <= 150 and 0 <= b.box[1] < b.box[3] <= 100 for b in out)


def test_committed_weights_find_objects_in_unseen_scenes(scenes: SceneRenderer) -> None:
    """Seeds 900000+ are never used for training (docs/perception.md): most visible
    objects are reported with the right class and a box at IoU >= 0.5, and few reports are
    false (the model card's numbers: mAP50 0.946 on seeds 500000+)."""
    assert WEIGHTS.exists(), f"the trained weights must be committed: {WEIGHTS}"
    cfg = det.DetectorConfig()
    d = det.Detector(cfg)
    hits = total = false_pos = 0
    for seed in range(900000, 900040):
        for f in scenes.render(seed):
            # what the service reports: scores >= 0.3, one class per object
            found = det.reported(d(f.rgb, f.depth), cfg.report_threshold, cfg.overlap_iou)
            truth = [lab for lab in f.labels if not lab.ignored]
            total += len(truth)
            used: set[int] = set()
            for lab in truth:
                for i, x in enumerate(found):
                    if i not in used and x.label == lab.name and _iou(x.box, lab.box) >= 0.5:
                        hits += 1
                        used.add(i)
                        break
            false_pos += len(found) - len(used)
    assert total >= 10
    # measured with the committed weights: 59/60 found, 1 false (seeds 900000-900039; the
    # weights before the standing renders: 46/59, 11 false); the bars sit below that so a
    # regression, not noise, fails the test
    assert hits / total >= 0.85, f"recall {hits}/{total}"
    assert false_pos <= 0.1 * total, f"{false_pos} false detections of {total} objects"


def _iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    ua = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / ua if ua > 0 else 0.0
