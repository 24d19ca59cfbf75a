"""`services up --foxglove PORT`: a WebSocket client speaking Foxglove's protocol (advertise, subscribe, binary
message data) connects to the bridge and receives the scene and the steps of a live run. Port 0: the bridge binds a
free one, writes it to the run's state/foxglove.port, and the launcher prints the address once it listens."""

from __future__ import annotations

import asyncio
import json
import struct
import time

import pytest

from .live import assert_nothing_left, start_up, wait_for

pytestmark = pytest.mark.live
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
WANTED = ("/step", "/scene/agent", "/scene/layout")


async def watch(port: int, deadline: float) -> tuple[dict, dict]:
    """Connect (retrying while the run starts), subscribe to WANTED as they are advertised; collect payloads.
    A wanted channel still silent 1.5 s after its subscription is subscribed once more under a new id (a subscribe
    that reached the server as it was still setting the channel up was seen lost, 1 run in 5)."""
    import aiohttp

    channels: dict[int, dict] = {}
    by_sub: dict[int, int] = {}  # subscription id -> channel id
    asked: dict[int, float] = {}  # channel id -> when last subscribed
    again: set[int] = set()  # channels subscribed a second time
    got: dict[str, list[bytes]] = {t: [] for t in WANTED}
    notes: list[str] = []  # the server's status messages, for the failure message
    async with aiohttp.ClientSession() as http:
        while True:
            try:
                ws = await http.ws_connect(f"ws://127.0.0.1:{port}", protocols=SUBPROTOCOLS)
                break
            except aiohttp.ClientError:
                if time.monotonic() > deadline:
                    raise
                await asyncio.sleep(0.2)
        info = None

        async def subscribe(ids: list[int]) -> None:
            subs = []
            for cid in ids:
                sub_id = len(by_sub) + 1
                by_sub[sub_id] = cid
                asked[cid] = time.monotonic()
                subs.append({"id": sub_id, "channelId": cid})
            await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))

        async with ws:
            while time.monotonic() < deadline and not all(len(v) >= 3 for v in got.values()):
                try:
                    msg = await ws.receive(timeout=0.5)
                except TimeoutError:
                    msg = None
                if msg is not None and msg.type == aiohttp.WSMsgType.TEXT:
                    body = json.loads(msg.data)
                    if body["op"] == "serverInfo":
                        info = body
                    elif body["op"] == "status":
                        notes.append(str(body.get("message"))[:200])
                    elif body["op"] == "advertise":
                        # a channel may be advertised again (the server re-advertises as channels appear):
                        # only new channel ids are subscribed here
                        new = [ch for ch in body["channels"] if ch["id"] not in channels]
                        channels.update({ch["id"]: ch for ch in new})
                        wanted = [ch["id"] for ch in new if ch["topic"] in WANTED]
                        if wanted:
                            await subscribe(wanted)
                elif msg is not None and msg.type == aiohttp.WSMsgType.BINARY:
                    data = msg.data
                    if data[0] == 0x01:  # message data: subscription id, log time, payload
                        sub_id, _ = struct.unpack_from("<IQ", data, 1)
                        got[channels[by_sub[sub_id]]["topic"]].append(bytes(data[13:]))
                elif msg is not None and msg.type in (
                    aiohttp.WSMsgType.CLOSE,
                    aiohttp.WSMsgType.CLOSED,
                    aiohttp.WSMsgType.ERROR,
                ):
                    break
                silent = [
                    cid
                    for cid, t in asked.items()
                    if cid not in again and not got[channels[cid]["topic"]] and time.monotonic() - t > 1.5
                ]
                if silent:
                    again.update(silent)
                    await subscribe(silent)
    return {"info": info, "channels": {c["topic"]: c for c in channels.values()}, "notes": notes}, got


def test_a_foxglove_client_receives_the_scene_and_the_steps(tmp_path):
    from common.protocol import SceneUpdate, Step

    launch = start_up(tmp_path, "fox", "--env", "maze", "--episodes", "4", "--rate", "25", "--foxglove", "0")
    port_file = launch.rundir / "state" / "foxglove.port"
    try:
        assert wait_for(port_file.exists, 60), "the bridge wrote no port"
        port = int(port_file.read_text())
        meta, got = asyncio.run(watch(port, time.monotonic() + 120))
    finally:
        rc = launch.wait(timeout=300)
    assert rc == 0, launch.out
    assert f"foxglove: ws://127.0.0.1:{port}" in launch.out
    assert_nothing_left(launch.rundir)
    assert meta["info"] is not None
    chans = meta["channels"]
    assert chans["/step"]["schemaName"] == "hitl.Step" and chans["/step"]["encoding"] == "json"
    assert chans["/scene/agent"]["schemaName"] == "foxglove.SceneUpdate"
    assert chans["/scene/agent"]["encoding"] == "protobuf"
    assert "/weights" not in chans  # the same channels as the log: not the actor's every-step weights
    assert all(len(got[t]) >= 1 for t in WANTED), ({t: len(v) for t, v in got.items()}, meta["notes"])
    steps = [Step.decode(b) for b in got["/step"]]
    assert [s.seq for s in steps] == sorted(s.seq for s in steps) and steps[0].run == "fox"
    agent = SceneUpdate.decode(got["/scene/agent"][-1])
    assert agent.entities[0].id == "agent" and agent.entities[0].spheres
    layout = SceneUpdate.decode(got["/scene/layout"][0])
    assert len(layout.entities[0].cubes) > 3


def test_the_bridge_serves_on_loopback_by_default():
    from services.common.config import FoxgloveConfig
    from services.launcher import UpConfig

    assert FoxgloveConfig().host == "127.0.0.1" and UpConfig().foxglove_host == "127.0.0.1"


def test_a_foxglove_port_out_of_range_is_one_line():
    """It was the bridge's config failing inside the launcher, a traceback."""
    from services.launcher import UpConfig

    with pytest.raises(ValueError, match=r"foxglove: port must be in 0\.\.65535 \(0: a free one\), got 70000"):
        UpConfig(foxglove=70000)


def test_a_restarted_bridge_serves_on_the_port_it_wrote(tmp_path):
    """Port 0: the first bridge of a run takes the system's port; a restarted one (the launcher restarts a dead
    service) serves where the printed address points, from the port file."""
    from services.common.statefiles import port_to_bind

    port_file = tmp_path / "foxglove.port"
    assert port_to_bind(0, str(port_file)) == 0
    port_file.write_text("43210")
    assert port_to_bind(0, str(port_file)) == 43210
    assert port_to_bind(8765, str(port_file)) == 8765  # (a port given: that one)
    port_file.write_text("")  # (damaged: the system's choice again)
    assert port_to_bind(0, str(port_file)) == 0
