"""The key table of the test helpers: the product's table plus the tests' own keys.

The bus refuses keys that are not in its table, so the helper services (``relay.py``,
``counter.py``) and the test processes that talk to them open their buses with
:data:`TABLE`; the product's table never carries test keys.
"""

from __future__ import annotations

import qm_examples
from quadmanip.common import keys
from quadmanip.common.messages import Clock
from quadmanip.common.schema import message_types


def _echo_rows() -> tuple[keys.Topic, ...]:
    rows = []
    for t in message_types():
        s = qm_examples.slug(t)
        rows.append(keys.row("test", f"in/{s}", t, "event", "in", f"relay input ({t.__name__})"))
        rows.append(keys.row("test", f"out/{s}", t, "event", "out", f"relay echo ({t.__name__})"))
    return tuple(rows)


TABLE = keys.TABLE.extended(
    (
        *_echo_rows(),
        keys.row("test", "counter", Clock, "control", "out", "router-restart counter"),
        keys.row("test", "isolation", Clock, "event", "out", "isolation check"),
        keys.row("test", "forget", Clock, "event", "out", "unclosed-bus check"),
    ),
    (
        keys.action_row("relay", "count", Clock, "count to N with feedback"),
        keys.action_row("nobody", "nothing", Clock, "an action no process serves"),
    ),
    services=("relay", "counterpub", "countersub", "probe"),
)
