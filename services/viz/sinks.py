"""Where the recording goes: an .rrd file and/or a live viewer, closed within the stop budget.

The file and the live sinks are two recording streams (same recording id, so a viewer
treats them as one recording), not one stream with two sinks: a gRPC sink whose viewer is
unreachable blocks for ~5 s when attached and again when closed (measured with
rerun-sdk 0.41), and with both sinks on one stream the file's footer would wait behind it.
Here the file closes first, on its own; the live stream gets a bounded, abandonable close.
"""

from __future__ import annotations

import threading
import time
import uuid
from pathlib import Path
from typing import Any

import rerun as rr
from quadmanip.services.viz import rerun_logging as rl

__all__ = ["Recordings", "open_recordings", "resolve_output"]


def resolve_output(template: str, now: float | None = None) -> Path:
    """``{time}`` → UTC ``YYYYmmdd_HHMMSS``; parent folders created."""
    stamp = time.strftime("%Y%m%d_%H%M%S", time.gmtime(time.time() if now is None else now))
    path = Path(template.replace("{time}", stamp)).expanduser()
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


class Recordings:
    """The file stream and/or the live stream, presented as one ``RecordingLike``
    (``log`` and ``set_time`` go to both)."""

    def __init__(self, file: rr.RecordingStream | None, live: rr.RecordingStream | None) -> None:
        self.file = file
        self.live = live
        self.streams = [s for s in (file, live) if s is not None]
        if not self.streams:
            raise ValueError("no recording sink")

    def log(self, entity_path: str, *args: Any, **kwargs: Any) -> None:
        for s in self.streams:
            s.log(entity_path, *args, **kwargs)

    def set_time(self, timeline: str, **kwargs: Any) -> None:
        for s in self.streams:
            s.set_time(timeline, **kwargs)

    def send_columns(self, entity_path: str, indexes: Any, columns: Any) -> None:
        for s in self.streams:
            s.send_columns(entity_path, indexes=indexes, columns=columns)

    def close(self, timeout: float) -> dict[str, bool]:
        """Flush and close: the file (complete with its footer) within ``timeout``, then the
        live stream in a daemon thread, abandoned after a short wait if its viewer is gone.
        Returns which closed cleanly."""
        done: dict[str, bool] = {}
        if self.file is not None:
            try:
                self.file.flush(timeout_sec=timeout)
                done["file"] = True
            except Exception:  # noqa: BLE001 - still close the file
                done["file"] = False
            self.file.disconnect()  # drops the FileSink: the footer is written
        if self.live is not None:
            live = self.live

            def _close() -> None:
                try:
                    live.flush(timeout_sec=0.2)
                except Exception:  # noqa: BLE001 - an unreachable viewer
                    pass
                live.disconnect()

            t = threading.Thread(target=_close, name="viz-live-close", daemon=True)
            t.start()
            t.join(0.3)
            done["live"] = not t.is_alive()
            if t.is_alive():
                # Rerun's exit hook would wait for the viewer again (seconds): skip it, the
                # file is already complete.
                rr.unregister_shutdown()
        return done


def open_recordings(
    application_id: str,
    output: str = "",
    connect_url: str = "",
    serve_port: int = 0,
    recording_id: str | None = None,
) -> tuple[Recordings, list[str]]:
    """Streams for the configured sinks, the default blueprint and the static layout.

    Returns the :class:`Recordings` and a description of each sink. Attaching a
    ``connect_url`` whose viewer is not up blocks ~5 s (Rerun's connect wait).
    """
    rid = recording_id or str(uuid.uuid4())
    where: list[str] = []
    file = live = None
    if output:
        path = resolve_output(output)
        file = rr.RecordingStream(application_id, recording_id=rid)
        file.set_sinks(rr.FileSink(str(path)), default_blueprint=rl.blueprint())
        where.append(f"file:{path}")
    live_sinks: list[Any] = []
    if connect_url:
        live_sinks.append(rr.GrpcSink(connect_url))
        where.append(f"viewer:{connect_url}")
    if serve_port:
        server = rr.GrpcServerSink(port=serve_port)
        live_sinks.append(server)
        where.append(f"serve:{server.uri}")
    if live_sinks:
        live = rr.RecordingStream(application_id, recording_id=rid)
        live.set_sinks(*live_sinks, default_blueprint=rl.blueprint())
    recs = Recordings(file, live)
    rl.log_static_layout(recs)
    return recs, where
