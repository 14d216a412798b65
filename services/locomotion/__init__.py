"""Locomotion service: state estimator, gait, convex MPC (PIQP), swing legs, Zenoh node."""
