"""`services up --foxglove PORT`: a WebSocket client speaking Foxglove's protocol (advertise, subscribe, binary
message data) connects to the bridge and receives the scene and the steps of a live run."""
from __future__ import annotations

import asyncio
import json
import struct
import time

import pytest

from common.transport import free_port

from .live import assert_nothing_left, start_up

pytestmark = pytest.mark.live
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
WANTED = ("/step", "/scene/agent", "/scene/layout")


async def watch(port: int, deadline: float) -> tuple[dict, dict]:
    """Connect (retrying while the run starts), subscribe to WANTED as they are advertised; collect payloads."""
    import aiohttp

    channels: dict[int, dict] = {}
    got: dict[str, list[bytes]] = {t: [] for t in WANTED}
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
        async with ws:
            while time.monotonic() < deadline and not all(len(v) >= 3 for v in got.values()):
                try:
                    msg = await ws.receive(timeout=max(0.1, deadline - time.monotonic()))
                except asyncio.TimeoutError:
                    break
                if msg.type == aiohttp.WSMsgType.TEXT:
                    body = json.loads(msg.data)
                    if body["op"] == "serverInfo":
                        info = body
                    elif body["op"] == "advertise":
                        subs = []
                        for ch in body["channels"]:
                            # a channel may be advertised again (the server re-advertises as channels appear):
                            # subscribing twice with the same id is refused and loses the subscription
                            if ch["id"] in channels:
                                continue
                            channels[ch["id"]] = ch
                            if ch["topic"] in WANTED:
                                subs.append({"id": ch["id"], "channelId": ch["id"]})
                        if subs:
                            await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))
                elif msg.type == aiohttp.WSMsgType.BINARY:
                    data = msg.data
                    if data[0] == 0x01:  # message data: subscription id, log time, payload
                        sub_id, _ = struct.unpack_from("<IQ", data, 1)
                        got[channels[sub_id]["topic"]].append(bytes(data[13:]))
                elif msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                    break
    return {"info": info, "channels": {c["topic"]: c for c in channels.values()}}, got


def test_a_foxglove_client_receives_the_scene_and_the_steps(tmp_path):
    from common.protocol import SceneUpdate, Step

    port = free_port()
    launch = start_up(tmp_path, "fox", "--env", "maze", "--episodes", "4", "--rate", "25", "--foxglove", str(port))
    try:
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
    assert all(len(got[t]) >= 1 for t in WANTED), {t: len(v) for t, v in got.items()}
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
