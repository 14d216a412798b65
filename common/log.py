"""Structured, one-line logs tagged with the service name.

Every record is one line: ``<UTC time> <LEVEL> <service> <message> key=value ...`` so that
``quadmanip up`` can prefix and interleave the logs of many processes and a grep on a key
(``goal_id=...``) still works. ``QM_LOG_JSON=1`` switches to one JSON object per line (for
log collectors); ``QM_LOG_LEVEL`` sets the level (default INFO).

Usage::

    from quadmanip.common.log import configure_logging, get_logger
    configure_logging("locomotion")
    log = get_logger("locomotion.mpc")
    log.info("solved", iters=7, dt_ms=1.9)
    log.throttled("mpc-fail", 1.0, logging.WARNING, "solver failed", status=3)
"""

from __future__ import annotations

import json
import logging
import os
import sys
import threading
import time
from collections.abc import Mapping, MutableMapping
from typing import Any

__all__ = ["StructuredLogger", "configure_logging", "get_logger", "service_name"]

_service = os.environ.get("QM_SERVICE", "") or "quadmanip"
_RESERVED = {"exc_info", "stack_info", "stacklevel", "extra"}


def service_name() -> str:
    """The service name that log lines of this process carry."""
    return _service


def _fmt_value(value: Any) -> str:
    if isinstance(value, float):
        text = f"{value:.6g}"
    else:
        text = str(value)
    if text == "" or any(c in text for c in ' ="\n'):
        return json.dumps(text)
    return text


class _LineFormatter(logging.Formatter):
    def __init__(self, as_json: bool) -> None:
        super().__init__()
        self.as_json = as_json

    def format(self, record: logging.LogRecord) -> str:
        fields: Mapping[str, Any] = getattr(record, "fields", None) or {}
        service = getattr(record, "service", None) or _service
        ts = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
        ts += f".{int(record.msecs):03d}Z"
        msg = record.getMessage()
        exc = self.formatException(record.exc_info) if record.exc_info else ""
        if self.as_json:
            obj: dict[str, Any] = {
                "time": ts,
                "level": record.levelname,
                "service": service,
                "logger": record.name,
                "message": msg,
            }
            obj.update({k: v for k, v in fields.items() if k not in obj})
            if exc:
                obj["exception"] = exc
            return json.dumps(obj, default=str)
        line = f"{ts} {record.levelname} {service} {msg}"
        if fields:
            line += " " + " ".join(f"{k}={_fmt_value(v)}" for k, v in fields.items())
        if exc:
            line += " exception=" + json.dumps(exc)
        return line


class StructuredLogger(logging.LoggerAdapter):
    """A logger whose calls take ``key=value`` fields: ``log.info("msg", tick=3)``."""

    def __init__(self, logger: logging.Logger) -> None:
        super().__init__(logger, {})
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._lock = threading.Lock()

    def process(self, msg: Any, kwargs: MutableMapping[str, Any]) -> tuple[Any, Any]:
        fields = {k: kwargs.pop(k) for k in list(kwargs) if k not in _RESERVED}
        extra = dict(kwargs.get("extra") or {})
        extra["fields"] = {**extra.get("fields", {}), **fields}
        kwargs["extra"] = extra
        return msg, kwargs

    def throttled(
        self, throttle_key: str, period_s: float, level: int, msg: str, /, **fields: Any
    ) -> bool:
        """Log at most once per ``period_s`` for ``throttle_key``; counts the suppressed.

        Returns True when the record was emitted. Used for per-message errors (a flood of
        malformed packets must not flood the log nor slow the receiving thread).
        """
        now = time.monotonic()
        with self._lock:
            last = self._last.get(throttle_key)
            if last is not None and now - last < period_s:
                self._suppressed[throttle_key] = self._suppressed.get(throttle_key, 0) + 1
                return False
            self._last[throttle_key] = now
            suppressed = self._suppressed.pop(throttle_key, 0)
        if suppressed:
            fields["suppressed"] = suppressed
        self.log(level, msg, **fields)
        return True


_configured = False
_config_lock = threading.Lock()


def configure_logging(
    service: str | None = None, level: int | str | None = None, as_json: bool | None = None
) -> None:
    """Install the one-line (or JSON) formatter on the root logger, stderr; idempotent.

    ``service`` names this process in every line; level and JSON default to the
    ``QM_LOG_LEVEL`` / ``QM_LOG_JSON`` environment variables.
    """
    global _service, _configured
    if service:
        _service = service
    if level is None:
        level = os.environ.get("QM_LOG_LEVEL", "INFO").upper()
    if as_json is None:
        as_json = os.environ.get("QM_LOG_JSON", "").lower() in {"1", "true", "yes", "on"}
    with _config_lock:
        root = logging.getLogger()
        root.setLevel(level)
        handler = None
        for h in root.handlers:
            if getattr(h, "_qm_handler", False):
                handler = h
        if handler is None:
            handler = logging.StreamHandler(sys.stderr)
            handler._qm_handler = True  # type: ignore[attr-defined]
            root.addHandler(handler)
        handler.setFormatter(_LineFormatter(as_json))
        _configured = True


def get_logger(name: str) -> StructuredLogger:
    """A :class:`StructuredLogger` named ``quadmanip.<name>``."""
    if not name.startswith("quadmanip"):
        name = f"quadmanip.{name}"
    return StructuredLogger(logging.getLogger(name))
