"""Test and benchmark harnesses: in-process physics scenes and the full-stack trial runner.

Everything here plays the parts a later service or the judge will play (a standing body
instead of locomotion, grasp poses from ground truth instead of perception, walking on
ground truth instead of navigation). It may read ground truth; no service imports it.
"""
