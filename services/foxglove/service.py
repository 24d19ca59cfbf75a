"""`python -m services.foxglove`: a live run in Foxglove, over Foxglove's WebSocket protocol (foxglove-sdk's server).

Another subscriber of `hitl/<run>/**`, like the recorder, serving what the recorder writes: the same topics
(`/step`, `/scene/agent`, ...), the same schemas (JSON Schema, or Foxglove's protobuf scene), the same scene
drawn from the steps and credits (common/logs/scene.py), and not the actor's every-step weights. Foxglove connects
to ws://HOST:PORT (Open connection -> Foxglove WebSocket); the layout in docs/foxglove-layout.json shows it.
`python -m services up --foxglove PORT` starts it. It serves on 127.0.0.1 unless told otherwise.

It never slows the run: samples go into a drop-oldest queue (counted when dropped), and what a slow viewer
cannot take is dropped by the server's own per-client backlog.
"""

from __future__ import annotations

import json
import sys
import time

from common.protocol import ProtocolError, ServiceStatus, decode, log_topic, parse_key, run_prefix
from common.logs.scene import SceneBuilder, derived_records
from services.common.config import FoxgloveConfig
from services.common.runtime import ServiceRuntime, service_main
from services.common.statefiles import atomic_write, port_to_bind


class Channels:
    """One foxglove-sdk channel per key, created on first use with the topic and schema the log uses."""

    def __init__(self) -> None:
        self.by_key: dict[str, object] = {}

    def log(self, key: str, data: bytes, log_time: int) -> None:
        import foxglove

        from common.logs.mcap_log import schema_record

        ch = self.by_key.get(key)
        if ch is None:
            cls = parse_key(key).spec.message
            encoding, schema = schema_record(cls)
            ch = self.by_key[key] = foxglove.Channel(
                log_topic(key),
                message_encoding=cls.MESSAGE_ENCODING,
                schema=foxglove.Schema(name=cls.TYPE_NAME, encoding=encoding, data=schema),
            )
        ch.log(data, log_time=log_time)


def load_scene(config: FoxgloveConfig) -> SceneBuilder | None:
    if not config.run_config:
        return None
    with open(config.run_config) as fh:
        return SceneBuilder.from_run_config(json.load(fh))


def main(config: FoxgloveConfig) -> int:
    import foxglove

    from common.wire.transport import subscription

    rt = ServiceRuntime("foxglove", config)
    scene = load_scene(config)
    port = port_to_bind(config.port, config.port_file)  # (port 0: a restarted bridge keeps its printed address)
    server = foxglove.start_server(name=f"hitl-tamer {config.run}", host=config.host, port=port)
    rt.log(f"serving ws://{config.host}:{server.port} (Foxglove: open connection, Foxglove WebSocket)")
    if config.port_file is not None:  # (port 0: the port the server took)
        atomic_write(config.port_file, str(server.port).encode())
    channels = Channels()
    stopped: set[str] = set()
    linger_until: float | None = None
    try:
        with (
            rt.session() as session,
            subscription(session, run_prefix(config.run), maxsize=1 << 14, policy="drop_oldest") as inbox,
        ):
            rt.ready()
            while True:
                if rt.stop.is_set() and linger_until is None:
                    linger_until = time.monotonic()
                if linger_until is not None and time.monotonic() >= linger_until:
                    break
                item = inbox.get(timeout=0.05)
                if item is not None:
                    try:
                        msg = decode(item.key, item.data)
                    except ProtocolError as e:
                        rt.counters[f"rejected_{e.reason}"] += 1
                        continue
                    t = int(item.t_recv * 1e9)
                    if parse_key(item.key).spec.logged:
                        channels.log(item.key, item.data, t)
                        rt.counters["messages_served"] += 1
                    for key, data in derived_records(config.run, msg, scene):  # carried Credits, the scene
                        channels.log(key, data, t)
                    if isinstance(msg, ServiceStatus) and msg.state == "stopped" and config.stop_when:
                        stopped.add(msg.service)
                        if linger_until is None and set(config.stop_when) <= stopped:
                            linger_until = time.monotonic() + config.linger
                rt.tick()
            rt.counters.update({f"inbox_{k}": v for k, v in inbox.snapshot().items()})
    finally:
        server.stop()
    rt.write_stats()
    rt.log(f"stopped: {rt.counters['messages_served']} messages served")
    return 0


def cli(argv: list[str] | None = None) -> int:
    """`python -m services.foxglove --flags` bridges a run to Foxglove; `python -m services.foxglove layout`
    prints the layout of docs/foxglove-layout.json."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv == ["layout"]:
        from services.foxglove.layout import layout_json

        sys.stdout.write(layout_json())
        return 0
    return service_main(
        FoxgloveConfig,
        main,
        argv,
        "python -m services.foxglove",
        also="Also: python -m services.foxglove layout (prints docs/foxglove-layout.json).",
    )
