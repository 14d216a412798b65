"""Benchmarks and test harnesses: everything that plays a part the runtime never plays.

The modules here stand in for services or the judge (a standing body instead of
locomotion, grasp poses from ground truth instead of perception, walking on ground truth
instead of navigation) and time or score the real ones. They may read ground truth and
import anything. Nothing in the runtime (``services/``, ``common/``, ``sim/``) imports
them; import-linter enforces it (``pyproject.toml``, ``[tool.importlinter]``).

- ``bench_bus``, ``bench_sim``, ``bench_locomotion``, ``bench_manipulation``: the
  ``quadmanip bench <target>`` commands (JSON out).
- ``locomotion_plant``, ``manipulation_scenes``: in-process physics scenes for tests.
- ``stack``, ``stack_trials``, ``stack_record``: full-stack trials over Zenoh.
- ``manipulation_record``: films of in-process runs.
"""
