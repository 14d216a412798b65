"""The visualisation service: a Zenoh → Rerun bridge (live viewer or ``.rrd`` recording).

``rerun_logging`` turns decoded messages into Rerun archetypes (no transport);
``node`` subscribes to the bus and feeds it. See docs/viz.md.
"""
