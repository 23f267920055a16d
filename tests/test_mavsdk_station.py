"""A MAVSDK app of the usual shape against an unsigned SITL fleet (the real MAVSDK from PyPI, `mavsdk>=4.1`, in the
test extras): connect to one robot, wait for its position, read home, attitude, GPS, flight mode, health and a typed
parameter, arm, upload a three-item mission, start it, watch the progress to the end (items done by any robot of the
fleet count), is_mission_finished, then hold and return to launch.  MAVSDK cannot sign, so the fleet runs with
--no-signing; the fleet is lock-stepped in a thread of this process (MAVSDK's timeouts are wall time; the robots
answer within a control cycle, which the stepping thread runs faster than real time), loopback only, free ports."""
from __future__ import annotations

import asyncio
import math
import threading

import pymap3d
import pytest

mavsdk = pytest.importorskip("mavsdk", minversion="4.1")

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync  # noqa: E402
from mavsdk.asyncio.plugins.param import ParamAsync  # noqa: E402
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync  # noqa: E402
from mavsdk.plugins.mission_raw import MissionItem  # noqa: E402
from mavsdk.plugins.telemetry import FixType, FlightMode  # noqa: E402

from sitl import launcher  # noqa: E402
from tests.sitl_util import port_block, shipped_fleet  # noqa: E402

GOALS = [(-1.0, -2.0), (-1.0, 2.0), (-2.0, 0.0)]            # fleet frame (m, ENU)
START = {1: (-2.0, -2.0), 2: (-2.0, 2.0)}                    # the two robots, facing east
STEP = 20.0                                                  # s: the longest any single wait may take (wall)


class Stepper:
    """The lock-step fleet, stepped in a thread until stopped."""

    def __init__(self, run):
        self.run = run
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        try:
            while not self.stop.is_set():
                self.run.step()
        except BaseException as e:          # the test reports it
            self.error = e

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=30)


def _build(tmp_path, listed: bool = False):
    """The two-robot fleet, lock-stepped, unsigned (``listed``: signed, taking unsigned ground-station frames from
    127.0.0.1/32 as ``--unsigned-gcs`` sets it), on free ports away from the block other SITL tests search first
    (an unsigned robot takes any frame sent to its port); a block taken between the search and the bind: another."""
    from runtime.errors import InputError

    for attempt in range(3):
        path = shipped_fleet(tmp_path, "operator_4.yaml", ports_from=port_block(22600) + 40 * attempt,
                             robots=[{"id": rid, "start": [x, y, 0.0]} for rid, (x, y) in START.items()])
        f = launcher.build(path, tmp_path / f"run{attempt}", signing=listed,
                           unsigned_gcs=["127.0.0.1/32"] if listed else None)
        try:
            return f, launcher.Lockstep(f)
        except InputError as e:
            f.close()
            if "Address already in use" not in str(e) or attempt == 2:
                raise


@pytest.fixture
def fleet(tmp_path, request):
    f, run = _build(tmp_path, listed=getattr(request, "param", "unsigned") == "listed")
    stepper = Stepper(run)
    try:
        yield f, stepper
    finally:
        stepper.close()
        run.close()
        f.close()
    assert stepper.error is None, stepper.error


async def within(what: str, aw, timeout: float = STEP):
    """``aw`` awaited within ``timeout`` wall seconds, else a failure naming ``what``."""
    try:
        return await asyncio.wait_for(aw, timeout)
    except asyncio.TimeoutError:
        raise AssertionError(f"{what}: nothing within {timeout:g} s") from None


async def first(gen, pred=lambda v: True, timeout: float = STEP, what: str = "a value"):
    """The first value of the async generator ``gen`` that satisfies ``pred``, within ``timeout`` wall seconds."""
    async def _first():
        async for v in gen:
            if pred(v):
                return v
    try:
        return await within(what, _first(), timeout)
    finally:
        await gen.aclose()


async def finished(mission, timeout: float = STEP) -> bool:
    """is_mission_finished, asked until true (as apps poll it) for at most ``timeout`` wall seconds."""
    async def _poll():
        while not await mission.is_mission_finished():
            await asyncio.sleep(0.1)
        return True
    return await within("is_mission_finished", _poll(), timeout)


def _item(seq: int, lat: float, lon: float) -> MissionItem:
    return MissionItem(seq=seq, frame=6, command=16, current=int(seq == 0), autocontinue=1, param1=0.0,
                       param2=0.0, param3=0.0, param4=0.0, x=int(round(lat * 1e7)), y=int(round(lon * 1e7)), z=0.0,
                       mission_type=0)


async def app(port: int, datum) -> dict:
    """What a MAVSDK app does; returns what it saw."""
    seen: dict = {}
    mav = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        await within("add_any_connection", mav.add_any_connection(f"udpout://127.0.0.1:{port}"))
        system = await within("first_autopilot", mav.first_autopilot(STEP), STEP + 1)
        assert system is not None, "MAVSDK found no autopilot"
        tel, action, mission, param = (TelemetryAsync(system), ActionAsync(system), MissionRawAsync(system),
                                       ParamAsync(system))
        seen["position"] = await first(tel.subscribe_position(), lambda p: math.isfinite(p.latitude_deg),
                                       what="position")
        seen["home"] = await first(tel.subscribe_home(), lambda h: math.isfinite(h.latitude_deg), what="home")
        seen["attitude"] = await first(tel.subscribe_attitude_euler(), lambda a: math.isfinite(a.yaw_deg),
                                       what="attitude")
        seen["gps"] = await first(tel.subscribe_gps_info(), lambda g: g.fix_type != FixType.NO_FIX, what="gps fix")
        seen["velocity"] = await first(tel.subscribe_velocity_ned(), what="velocity")
        seen["battery"] = await first(tel.subscribe_battery(), what="battery")
        seen["health"] = await first(tel.subscribe_health(), lambda h: h.is_home_position_ok, what="health")
        seen["mode_idle"] = await first(tel.subscribe_flight_mode(), lambda m: m != FlightMode.UNKNOWN,
                                        what="a flight mode")
        seen["sys_armed"] = await within("get_param_int", param.get_param_int("SYS_ARMED"))
        seen["cruise"] = await within("get_param_float", param.get_param_float("CTL_CRUISE_SPD"))
        await within("arm", action.arm())
        seen["armed"] = await first(tel.subscribe_armed(), lambda a: a, what="armed")
        items = []
        for k, (x, y) in enumerate(GOALS):
            lat, lon, _ = pymap3d.enu2geodetic(x, y, 0.0, datum.lat, datum.lon, datum.alt)
            items.append(_item(k, lat, lon))
        progress = []
        watching = asyncio.ensure_future(_progress(mission, progress))
        await within("upload_mission", mission.upload_mission(items))
        await within("start_mission", mission.start_mission())
        seen["mode_mission"] = await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.MISSION,
                                           what="flight mode MISSION")
        await within("mission progress to the end", watching, 3 * STEP)
        seen["progress"] = progress
        seen["finished"] = await finished(mission)
        seen["downloaded"] = await within("download_mission", mission.download_mission())
        await within("pause_mission", mission.pause_mission())
        seen["mode_paused"] = await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD,
                                          what="flight mode HOLD after pause_mission")
        await within("return_to_launch", action.return_to_launch())
        seen["mode_rtl"] = await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.RETURN_TO_LAUNCH,
                                       what="mode_rtl")
        home = seen["home"]
        seen["back_home"] = await first(tel.subscribe_position(), lambda p: _metres(p, home) < 0.3, 3 * STEP,
                                        what="back at home")
        await within("hold", action.hold())
        seen["mode_hold"] = await first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD,
                                        what="flight mode HOLD after hold")
        await within("disarm", action.disarm())
        seen["disarmed"] = await first(tel.subscribe_armed(), lambda a: not a, what="disarmed")
        return seen
    finally:
        mav.destroy()


def _metres(p, q) -> float:
    """Ground distance (m) between two MAVSDK positions (latitude_deg, longitude_deg)."""
    e, n, _ = pymap3d.geodetic2enu(p.latitude_deg, p.longitude_deg, 0.0, q.latitude_deg, q.longitude_deg, 0.0)
    return math.hypot(e, n)


async def _progress(mission, out: list) -> None:
    async for p in mission.subscribe_mission_progress():
        out.append((p.current, p.total))
        if p.total == len(GOALS) and p.current == p.total:
            return


@pytest.mark.slow
@pytest.mark.parametrize("rid, fleet", [(1, "unsigned"), (2, "listed")], indirect=["fleet"])
def test_a_mavsdk_app_runs_a_fleet_mission_to_the_end(fleet, rid):
    """The app works with whichever robot it connects to; the others' work counts in its progress.  Robot 1's fleet
    is unsigned; robot 2's is signed and lists the app's network (comms.unsigned_gcs: 127.0.0.1/32), so the app's
    unsigned frames are taken there (MAVSDK cannot sign; its system id 245 is no robot's of the fleet)."""
    from runtime import config as C

    f, stepper = fleet
    robot = C.load_robot(f.robots[rid].config_path)
    sx, sy = START[rid]
    seen = asyncio.run(asyncio.wait_for(app(f.robots[rid].udp_port, robot.datum), 120))
    assert stepper.error is None, stepper.error
    done_by = dict(stepper.run.daemons[rid].core.node.done_by)
    link = stepper.run.daemons[rid].link
    assert (link.counters.unsigned_gcs_taken > 0) == link.signing        # signed: the app's frames came unsigned
    # telemetry a MAVSDK app reads
    d = robot.datum
    e, n, _ = pymap3d.geodetic2enu(seen["position"].latitude_deg, seen["position"].longitude_deg, 0.0, d.lat, d.lon,
                                   d.alt)
    assert math.hypot(e - sx, n - sy) < 1.0                                     # where the robot starts
    e, n, _ = pymap3d.geodetic2enu(seen["home"].latitude_deg, seen["home"].longitude_deg, 0.0, d.lat, d.lon, d.alt)
    assert math.hypot(e - sx, n - sy) < 1.0                                     # home: where it started
    assert abs(seen["attitude"].yaw_deg - 90.0) < 20.0                          # facing east (ENU 0) = NED 90
    assert seen["gps"].fix_type in (FixType.FIX_3D, FixType.FIX_2D) and seen["gps"].num_satellites > 0
    h = seen["health"]
    assert h.is_gyrometer_calibration_ok and h.is_accelerometer_calibration_ok and h.is_magnetometer_calibration_ok
    assert seen["mode_idle"] == FlightMode.HOLD and seen["sys_armed"] == 1 and 0.0 < seen["cruise"] <= 0.5
    # the mission: progress counts what the fleet did, to the end
    assert seen["progress"][-1] == (len(GOALS), len(GOALS)), seen["progress"]
    assert seen["finished"] is True
    assert len(done_by) == len(GOALS) and any(set(who) - {rid} for who in done_by.values()), done_by  # others helped
    assert len(seen["downloaded"]) == len(GOALS)
    assert seen["mode_mission"] == FlightMode.MISSION and seen["mode_rtl"] == FlightMode.RETURN_TO_LAUNCH
