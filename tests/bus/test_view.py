"""The live view (``aider-exo view``): its model from a lock-step walk's frames (the controller's
own estimates, gait states, steps, node health, rejections), its server (snapshots over a
WebSocket, token, malformed requests, slow browsers, ten at once), and the command."""

from __future__ import annotations

import asyncio
import json
import threading
from typing import NamedTuple

import numpy as np
import pytest
from aiohttp import WSMsgType
from aiohttp.test_utils import TestClient, TestServer

from config import default_config_path, load_config, with_overrides
from config.errors import AiderError
from protocol.bus import virtual_bus
from protocol.catalog import default_catalog
from protocol.codec import Codec
from protocol.e2e import Transmitter
from tools.cli import main
from tools.pipeline import walk
from tools.trace.reader import Frame, ReadReport, read_frames
from tools.view import make_feed
from tools.view.model import SERIES
from tools.view.server import Client, ViewServer, check_bind
from tools.view.source import Feed, ListenOnly

CFG = load_config(default_config_path())


class Walked(NamedTuple):
    frames: list
    estimates: dict  # tick -> the controller's CoM estimate
    steps: list  # the controller's step records


@pytest.fixture(scope="module")
def walked():
    """The frames of a two-cycle lock-step walk (over 10 s) as a listener on its bus saw them, and the
    controller's own estimate of every tick."""
    channel = "view-walk"
    estimates: dict[int, np.ndarray] = {}
    with virtual_bus(channel) as listener:
        outcome = walk(CFG, cycles=2, seed=0, channel=channel, compare_ratio=False,
                       on_tick=lambda r, session, host: estimates.__setitem__(r.tick, None if r.estimate is None else r.estimate.com))
        frames = []
        while (msg := listener.recv(0)) is not None:
            frames.append(Frame.from_message(msg))
    assert outcome.cycles_completed == 2 and not outcome.fell
    return Walked(frames, estimates, outcome.steps)


def _fed(frames, upto=None):
    feed = make_feed(CFG)
    for f in frames[:upto]:
        feed.put(f)
    return feed


def test_the_model_runs_the_controllers_estimator_on_the_bus_and_gets_its_estimates(walked):
    frames, estimates = walked.frames, walked.estimates
    model = make_feed(CFG).model
    sync = default_catalog().by_name("SYNC").frame_id
    compared = 0
    for f in frames:
        if f.arbitration_id == sync and model.tick is not None and model.tick in estimates:
            tick = model.tick
            model.feed(f)  # the next SYNC closes the tick: the view's estimate of it
            if estimates[tick] is not None:
                np.testing.assert_allclose(model.estimate.com, estimates[tick], rtol=0, atol=1e-12)
                compared += 1
            continue
        model.feed(f)
    assert compared > 500  # every tick of the walk with its sensors in


def test_the_model_follows_the_gait_counts_steps_and_keeps_the_health_of_every_node(walked):
    frames = walked.frames
    model = make_feed(CFG).model
    states = []
    for f in frames:
        model.feed(f)
        if not states or states[-1] != model.gait_state:
            states.append(model.gait_state)
    assert {"DOUBLE_SUPPORT", "SWING_LEFT", "SWING_RIGHT"} <= set(states)
    assert model.steps == len(walked.steps) == 4 and model.landings >= 1  # two cycles
    placed = [s["length_m"] for s in model.landed]
    assert placed and all(0.05 < x < 0.3 for x in placed)  # feet apart at landing, from the estimator's ankles
    snap = model.snapshot()
    assert snap["receiver"]["accepted"] == len(frames) and snap["receiver"]["rejected_by_reason"] == {}
    assert {n["nmt"] for n in snap["nodes"].values()} == {"OPERATIONAL"}
    assert all(n["heartbeat_age_s"] <= 0.12 and n["drive_state"] == "TRACK" for n in snap["nodes"].values())
    assert 0.05 < snap["bus_load"] < 0.25
    est = snap["estimate"]
    assert len(est["support"]) >= 3 and 0.7 < est["com"][2] - est["floor_z"] < 1.2  # the origin: midway between the hips


def test_the_controllers_telemetry_frames_give_its_steps_and_theta(walked):
    frames = walked.frames
    model = _fed(frames).model
    step, learning = model.snapshot()["gait"]["controller_step"], model.snapshot()["learning"]
    steps = walked.steps
    assert step["index"] == len(steps) == 4 and step["policy"] == "COMPENSATED"
    assert step["commanded_m"] == pytest.approx(steps[-1].length_m, abs=0.0005)
    assert step["placed_m"] == pytest.approx(steps[-2].placed_m, abs=0.0005)
    # the last landed step's cost (the walk may end before the next frame tells the final landing)
    assert any(step["cost_n"] == pytest.approx(st.mean_stick_force_n, abs=0.25) for st in steps if st.landed)
    assert (learning["alpha"], learning["xhat_com"]) == pytest.approx(steps[-1].theta, abs=0.005)
    assert learning["update"] == 0 and learning["costs"] == []  # not learning


def test_a_swing_has_its_commanded_and_measured_ankle_path(walked):
    frames = walked.frames
    model = make_feed(CFG).model
    seen = 0
    for f in frames:
        model.feed(f)
        if model.swing_leg is not None:
            seen = max(seen, len(model.paths["commanded"]))
            cmd, meas = model.paths["commanded"], model.paths["measured"]
    assert seen > 20
    assert len(cmd) == len(meas)
    # the measured ankle follows the commanded one within a few centimetres
    assert max(abs(a[0] - b[0]) + abs(a[1] - b[1]) for a, b in zip(cmd, meas)) < 0.08
    assert max(z for _, z in cmd) > 0.1  # the swing lifts the foot


def test_the_series_are_numbered_so_a_client_gets_only_what_is_new_and_ten_seconds_at_most(walked):
    frames = walked.frames
    model = _fed(frames).model
    full = model.snapshot()["series"]
    assert full["fields"] == ["n", "t", *SERIES]
    samples = full["samples"]
    assert len(samples) == 500  # 10 s of 20 ms ticks
    assert samples[-1][1] - samples[0][1] == pytest.approx(9.98, abs=0.03)
    last = samples[-1][0]
    assert model.snapshot(last)["series"]["samples"] == []
    assert [s[0] for s in model.snapshot(last - 3)["series"]["samples"]] == [last - 2, last - 1, last]


def test_rejected_frames_are_counted_by_reason_and_an_emcy_is_listed_with_its_code():
    codec = Codec()
    model = make_feed(CFG).model
    tx = Transmitter(codec)
    name = "EMCY_RH"
    msg = tx.message(name, (0x2310, 1, 7))
    model.feed(Frame(1.0, msg.arbitration_id, bytes(msg.data)))
    bad = bytearray(tx.message(name, (0x2310, 1, 7)).data)
    bad[0] ^= 0xFF  # the CRC
    model.feed(Frame(1.1, msg.arbitration_id, bytes(bad)))
    model.feed(Frame(1.2, 0x7FF, b"\x00"))
    snap = model.snapshot()
    assert snap["emcy"] == [{"t": 0.0, "node": "RIGHT_HIP", "code": "OVER_CURRENT", "register": 1, "detail": 7}]
    assert snap["receiver"]["rejected_by_reason"] == {"bad_crc": 1, "unknown_id": 1}
    assert snap["frames"] == 3 and snap["t"] == 0 and snap["tick"] is None  # no SYNC yet: the time of tick 0


def test_the_view_cannot_send_on_its_bus():
    with virtual_bus("view-listen-only") as raw:
        bus = ListenOnly(raw)
        with pytest.raises(AiderError, match="never sends"):
            bus.send(None)
        assert bus.sends_refused == 1


def test_a_stopped_reader_still_reads_the_frames_sent_before_the_stop(walked):
    """A walk's view ends complete even when its reader lags: stopping it reads what is queued."""
    from tools.view.source import BusReader

    with virtual_bus("view-drain") as raw, virtual_bus("view-drain") as sender:
        feed = make_feed(CFG)
        reader = BusReader(ListenOnly(raw), feed)
        for f in walked.frames[:3000]:
            sender.send(f.to_message())
        reader.stop()  # before it has read a frame
        reader.start()
        reader.join(timeout=30)
    assert feed.model.frames == 3000 and reader.error is None


# -- server ----------------------------------------------------------------------------------------


def test_off_loopback_the_view_needs_a_token():
    check_bind("127.0.0.1", None)
    check_bind("::1", None)
    check_bind("0.0.0.0", "s3cret")
    with pytest.raises(AiderError, match="--token"):
        check_bind("0.0.0.0", None)
    with pytest.raises(AiderError, match="--token"):
        ViewServer(Feed(make_feed(CFG).model), host="192.168.1.5")


def _serve(feed, check, **kwargs):
    async def run():
        server = ViewServer(feed, port=0, **kwargs)
        async with TestClient(TestServer(server.app())) as client:
            task = asyncio.create_task(server._broadcast())
            try:
                await check(server, client)
            finally:
                task.cancel()

    asyncio.run(run())


async def _receive(ws, n):
    out = []
    while len(out) < n:
        msg = await asyncio.wait_for(ws.receive(), 5)
        assert msg.type == WSMsgType.TEXT
        out.append(json.loads(msg.data))
    return out


def test_the_page_and_its_assets_are_served_and_a_browser_gets_a_full_snapshot_then_deltas(walked):
    feed = _fed(walked.frames)

    async def check(server, client):
        page = await client.get("/")
        assert page.status == 200 and "view.js" in await page.text()
        js = await client.get("/static/view.js")
        assert js.status == 200 and "WebSocket" in await js.text()
        assert (await client.get("/static/../../cli/view.py")).status in (403, 404)
        ws = await client.ws_connect("/ws")
        first, second = await _receive(ws, 2)
        assert first["kind"] == "full" and len(first["series"]["samples"]) == 500
        assert second["kind"] == "delta" and second["series"]["samples"] == []  # nothing new on the bus
        assert first["gait"]["steps"] == len(walked.steps) and first["stale_s"] is not None
        await ws.close()

    _serve(feed, check)


def test_with_a_token_a_browser_without_it_is_refused_and_counted(walked):
    feed = _fed(walked.frames, 2000)

    async def check(server, client):
        resp = await client.get("/ws")
        assert resp.status == 403
        ws = await client.ws_connect("/ws?token=s3cret")
        (snap,) = await _receive(ws, 1)
        assert snap["frames"] == 2000
        assert server.stats.refused == 1 and server.stats.connects == 1
        await ws.close()

    _serve(feed, check, token="s3cret")


def test_malformed_client_messages_are_ignored_and_counted(walked):
    feed = _fed(walked.frames, 500)

    async def check(server, client):
        ws = await client.ws_connect("/ws")
        await _receive(ws, 1)
        for text in ("not json", "[1, 2]", '{"type": "write_frame", "id": 513}', '{"type": "ping"}'):
            await ws.send_str(text)
        await ws.send_bytes(b"\x00\x01")
        await ws.send_str('{"type": "resync"}')
        for _ in range(20):
            snaps = await _receive(ws, 1)
            if snaps[0]["kind"] == "full":
                break
        else:
            pytest.fail("no full snapshot after a resync")
        assert server.stats.malformed == 4 and server.stats.resyncs == 1
        await ws.close()

    _serve(feed, check)


def test_a_browser_that_does_not_keep_up_loses_its_oldest_snapshots_and_gets_a_full_one(walked):
    feed = _fed(walked.frames)
    server = ViewServer(feed, port=0, queue_len=2)

    async def run():
        slow, quick = Client(asyncio.Queue(2)), Client(asyncio.Queue(100))
        server.clients |= {slow, quick}
        task = asyncio.create_task(server._broadcast())
        await asyncio.sleep(0.3)  # about 7 rounds; nobody takes from the queues
        task.cancel()
        return slow, quick

    slow, quick = asyncio.run(run())
    assert quick.dropped == 0 and quick.queue.qsize() >= 5
    assert slow.dropped >= 3 and server.stats.dropped == slow.dropped
    kinds = [json.loads(slow.queue.get_nowait())["kind"] for _ in range(slow.queue.qsize())]
    assert "full" in kinds and len(kinds) <= 2


def test_ten_browsers_are_served_at_once(walked):
    feed = _fed(walked.frames)

    async def check(server, client):
        sockets = [await client.ws_connect("/ws") for _ in range(10)]
        got = await asyncio.gather(*(_receive(ws, 4) for ws in sockets))
        assert all(len(g) == 4 and g[0]["kind"] == "full" for g in got)
        assert server.stats.clients == 10
        for ws in sockets:
            await ws.close()

    _serve(feed, check)


# -- the command -----------------------------------------------------------------------------------


def test_the_command_refuses_other_addresses_without_a_token_and_the_in_process_bus(capsys):
    assert main(["view", "--host", "0.0.0.0", "--duration", "1"]) == 1
    assert "give --token" in capsys.readouterr().err
    assert main(["view", "--bus", "virtual", "--duration", "1", "--port", "0"]) == 1
    assert "aider-exo walk --view" in capsys.readouterr().err


def test_the_view_plays_a_recorded_trace(tmp_path, capsys):
    trace = tmp_path / "walk.log"
    assert main(["trace", "record", str(trace), "--walk", "1", "--seed", "2"]) == 0
    capsys.readouterr()
    assert main(["view", "--trace", str(trace), "--speed", "0", "--port", "0", "--duration", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    recorded = len(list(read_frames([trace], ReadReport())))
    assert recorded > 5000 and out["frames"] == recorded and out["receiver"]["rejected_by_reason"] == {}
    assert out["gait"]["steps"] == 2 and out["sends_refused"] == 0 and out["reader_error"] is None



def test_walk_view_serves_the_walks_page_and_prints_its_address(capsys):
    assert main(["walk", "--steps", "1", "--view", "--view-port", "0", "--pace", "0", "--json", "--quiet"]) == 0
    out = capsys.readouterr()
    summary, view = json.loads(out.out), json.loads(out.out)["view"]
    assert f"aider-exo walk: live view at {view['url']}" in out.err and view["url"].startswith("http://127.0.0.1:")
    # the nodes' frames the controller accepted, and the controller's own (a SYNC a tick at least)
    assert summary["cycles_completed"] == 1 and view["frames"] >= summary["receiver"]["accepted"] + summary["ticks"]
    assert view["sends_refused"] == 0 and view["reader_error"] is None

# -- in a real browser -----------------------------------------------------------------------------


@pytest.mark.realtime  # paced on the wall clock: with the realtime stage, not beside other workers
def test_a_browser_follows_a_walk_and_shows_a_node_fault(tmp_path):
    """Headless chromium (playwright) on the page of a lock-step walk paced at 4 times real time:
    the gait state goes through DOUBLE_SUPPORT and both swings, the CoM marker moves, the stick-force
    plot grows, and the right knee's drive fault (injected after the first gait cycle) appears in the
    node table and the EMCY list; the page is saved as a screenshot. When the walk has ended the page
    says "no data since ..." and recovers at the next frame."""
    from tools.view import browser
    from tools.pipeline import Pace, walk_config
    from tools.view.live import LiveView

    if (why := browser.missing()) is not None:
        pytest.skip(why)
    fault_tick = 600  # the first gait cycle lands at tick 568 (seed 0)
    cfg = with_overrides(CFG, {"nodes.faults": {"f": {"kind": "drive_fault", "node": "RIGHT_KNEE", "start_tick": fault_tick}}})
    channel = "view-browser"
    view = LiveView(cfg, walk_config(cfg, "sagittal", channel).bus, port=0)
    pace = Pace(4.0)
    outcome: list = []
    walker = threading.Thread(target=lambda: outcome.append(
        walk(cfg, cycles=2, seed=0, channel=channel, compare_ratio=False, on_tick=lambda r, session, host: pace(r.tick))))
    try:
        url = view.start()
        with browser.Browser(url) as page:
            page.wait_for("document.getElementById('link').textContent === 'connected'", 20)
            walker.start()
            com_px, force_points = set(), []
            while walker.is_alive():
                com_px.add(page.data("#topdown", "com-px"))
                force_points.append(int(page.data("#plot-forces", "points")))
                walker.join(0.2)
            page.wait_for("document.querySelector('#nodes tr.fault') !== null", 10)
            # the controller's FAULT comes a tick after the node's (its EMCY), and may come in the
            # page's next update (every 40 ms; at 4 times real time a tick is 5 ms): wait for it too
            page.wait_for("window.viewStats.lastState === 'FAULT'", 10)
            fault_row = page.text("#nodes tr.fault")
            emcy = page.text("#emcy")
            stats = page.stats()
            shot = page.screenshot(tmp_path / "view.png")
            # The walk has ended: the page says so within a second or two, and recovers when frames return.
            page.wait_for("!document.getElementById('stale').hidden", 5)
            silent = page.text("#stale")
            with virtual_bus(channel) as bus:
                bus.send(Transmitter(Codec()).message("SYNC", (fault_tick + 100,)))
            page.wait_for("document.getElementById('stale').hidden", 5)
    finally:
        walker.join()
        report = view.close()
    assert outcome and outcome[0].fault is not None and outcome[0].cycles_completed == 1, outcome and outcome[0].summary()
    states = stats["states"]
    assert states[0] in ("UNKNOWN", "INIT", "STANDING"), states
    first_ds = states.index("DOUBLE_SUPPORT")
    assert {"SWING_LEFT", "SWING_RIGHT"} <= set(states[first_ds:]) and states[-1] == "FAULT", states
    assert stats["updates"] >= 20 * 2  # 25 a second for the walk's few seconds
    px = sorted(int(x) for x in com_px if x is not None)
    assert px and px[-1] - px[0] > 20, px  # the CoM marker moved over the feet and sticks ...
    shown = stats["xRatio"]  # every X_CoM/X_SP the page showed, not the few sampled here
    assert shown and shown["max"] - shown["min"] > 0.3, shown  # ... and through the support polygon
    # the stick-force plot grew to its 10 s (500 ticks), never shrinking before
    filling = force_points[:next((k for k, n in enumerate(force_points) if n >= 490), len(force_points))]
    assert force_points[0] < 100 and force_points[-1] >= 490 and filling == sorted(filling), force_points
    assert "RIGHT_KNEE" in fault_row and "FAULT" in fault_row and "OVER_CURRENT" in fault_row, fault_row
    assert "RIGHT_KNEE" in emcy and "OVER_CURRENT" in emcy, emcy
    assert report["sends_refused"] == 0 and report["reader_error"] is None
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000
    assert silent.startswith("no data since "), silent


@pytest.mark.vcan
def test_the_view_watches_a_walk_over_vcan0_and_sends_nothing(vcan0, tmp_path):
    """``aider-exo view`` on vcan0 while the controller and the nodes walk a gait cycle there as two
    processes, candump recording: every frame candump saw is one the controller or the nodes sent
    (the view sent none) and the view saw them all, with the walk's steps."""
    import signal
    import subprocess

    from tests.conftest import ROOT
    from tests.support.capture import recorded
    from tests.support.processes import AIDER, walk_two_processes

    view = subprocess.Popen([AIDER, "view", "--bus", "socketcan", "--channel", vcan0, "--port", "0", "--json"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        started = view.stderr.readline()  # "aider-exo view: socketcan:vcan0 at http://127.0.0.1:PORT/ (Ctrl-C stops)"
        assert " at http://127.0.0.1:" in started, started + view.stderr.read()
        log = tmp_path / "candump.log"
        summary, nodes = walk_two_processes("socketcan", vcan0, log, 1, lockstep=True)
    finally:
        view.send_signal(signal.SIGINT)
        out, err = view.communicate(timeout=60)
    assert view.returncode == 0, err
    seen = json.loads(out)
    recorded = recorded(log)
    assert summary["steps_completed"] == 2
    assert recorded == summary["frames_sent"] + nodes["frames_sent"]  # nothing on the bus but the walk's frames
    assert seen["sends_refused"] == 0 and seen["reader_error"] is None
    # The view saw every frame of the walk, and the probes of the recording, not in the DBC (some
    # sent before candump listened, repeated until it did, and the last one).
    probes = seen["receiver"]["rejected_by_reason"].pop("unknown_id", 0)
    assert seen["frames"] == recorded + probes and probes >= 2 and seen["receiver"]["rejected_by_reason"] == {}
    # Both swings seen in the controller's heartbeats (the last landing is not: the controller
    # stops at the tick it lands, before its next heartbeat).
    assert seen["gait"]["steps"] == 2


def test_view_screenshot_needs_a_trace_or_a_duration(capsys):
    assert main(["view", "--port", "0", "--screenshot", "x.png", "--bus", "udp_multicast"]) == 1
    assert "give --trace or --duration" in capsys.readouterr().err


@pytest.mark.realtime  # its walks are in real time
def test_the_view_benchmark_measures_both_settings_in_the_browser(tmp_path, capsys):
    """``aider-exo bench view`` on short walks: every figure is measured (its values are printed,
    never asserted here), the view sent nothing and the page was saved. Also ``view --screenshot``
    on a recorded trace."""
    from tools.view import browser

    if (why := browser.missing()) is not None:
        pytest.skip(why)
    shot = tmp_path / "bench.png"
    assert main(["bench", "view", "--max-ticks", "100", "--repeats", "1", "--json", "--screenshot", str(shot)]) == 0
    r = json.loads(capsys.readouterr().out)
    for key in ("beside_the_walk", "in_the_walks_process"):
        s = r[key]
        assert s["latency_ms"]["samples"] > 10 and s["updates_per_s"] > 0 and s["listener_cpu_percent"] >= 0
        work = s["controller_work_us"]
        assert len(work["without_view"]) == 2 and len(work["with_view"]) == 1
        assert all(w["ticks"] >= 100 and w["p99_ci_us"][0] <= w["p99_us"] <= w["p99_ci_us"][1] for w in work["without_view"] + work["with_view"])
        assert all(w["fall"] is None and w["fault"] is None for w in s["walks"]["without_view"] + s["walks"]["with_view"])
    assert r["beside_the_walk"]["screenshot"] == str(shot) and shot.read_bytes()[:4] == b"\x89PNG"

    trace = tmp_path / "walk.log"
    assert main(["trace", "record", str(trace), "--walk", "1", "--seed", "1"]) == 0
    capsys.readouterr()
    page = tmp_path / "trace.png"
    assert main(["view", "--trace", str(trace), "--speed", "0", "--port", "0", "--screenshot", str(page), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["screenshot"] == str(page) and page.read_bytes()[:4] == b"\x89PNG" and out["server"]["connects"] == 1
