"""Behavior: the tidy-up task (paper Sections 5 and 7.2) as an explicit state machine that
strings the other services' actions together. Algorithms live in plain modules
(``tidy_task.py``, ``coverage.py``, ``frames.py``); ``node.py`` wires them to Zenoh."""
