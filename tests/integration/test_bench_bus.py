"""A short `quadmanip bench bus` run between two real processes produces the full JSON."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest
from quadmanip.testbench.bench_bus import SUMMARY_FIELDS, TARGETS

pytestmark = pytest.mark.integration


def test_short_bench_bus_run_produces_every_summary_field(tmp_path):
    out = tmp_path / "bus.json"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "quadmanip.cli",
            "bench",
            "bus",
            "--json",
            str(out),
            "--count",
            "100",
            "--warmup",
            "20",
            "--rgbd-seconds",
            "0.5",
            "--codec-reps",
            "200",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert "[bench bus]" in result.stderr  # progress while it runs
    report = json.loads(out.read_text())

    summary = report["summary"]
    for name in SUMMARY_FIELDS:
        value = summary[name]
        assert isinstance(value, float) and math.isfinite(value) and value > 0, name
    assert summary["rtt_peer_p99_ms"] >= summary["rtt_peer_p50_ms"]
    assert summary["rtt_router_p99_ms"] >= summary["rtt_router_p50_ms"]
    # Every joint command came back (control QoS is reliable), in both topologies.
    for mode in ("peer", "router"):
        rtt = report["details"][mode]["rtt_joint_command_ms"]
        assert rtt["n"] == 100 and rtt["lost"] == 0
        assert report["details"][mode]["rtt_1kb_ms"]["bytes"] in range(1021, 1028)
        rgbd = report["details"][mode]["rgbd"]
        assert 0 < rgbd["received"] <= rgbd["sent"]
        # 320x240 RGB (1 B/px x3) + depth (4 B/px) is 537,600 bytes of pixels.
        assert rgbd["bytes"] > 320 * 240 * 7
    # A frame is ~70x the bytes of a joint message; its codec cost must be larger too.
    assert summary["codec_rgbd_us"] > summary["codec_joint_command_us"]

    assert set(report["targets"]) == set(TARGETS)
    for name, target in report["targets"].items():
        assert target["value"] == summary[name]
        assert isinstance(target["pass"], bool)
    assert report["all_targets_pass"] == all(t["pass"] for t in report["targets"].values())
    assert report["machine"]["cpu_count"] >= 1 and report["machine"]["eclipse-zenoh"]
