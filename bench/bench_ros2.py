"""The stdlib ROS 2 codec (bus_schemas.ros2) next to rosbags' compiled CDR codec, same run.

    python bench/bench_ros2.py               # codec table
    python bench/bench_ros2.py --bridge 400  # also: bus pose -> /r1/odom through `formation ros2`
    python bench/bench_ros2.py --cpu 3,100   # also: the bridge's CPU and added latency, N robots
    python bench/bench_ros2.py --backend 400 # also: the ros2 motor backend's cmd_vel latency

Codec: per message, the best of 15 rounds of 2,000 encodes / decodes (process CPU time per
message, microseconds) of ours and of rosbags' ``serialize_cdr`` / ``deserialize_cdr`` (the
baseline: pure Python code generated per type, plus numpy arrays). A robot runs ours: no numpy.

Bridge: a router and a ``formation ros2`` process; this process publishes ``Pose`` messages on
the bus and listens to ``/r1/odom`` on the ROS side; the latency is from the bus put to the
odometry's arrival (both on this host's monotonic clock). The baseline is the same round trip
without the bridge: a plain Zenoh put to a subscriber of this process through the same router.

Load (``--cpu 3,100``): this process publishes N robots' poses as the plant does (one ``poses``
batch at 30 Hz, the frame number in ``y``) for ``--window`` seconds, twice through the same
router: first without the bridge (latency from the put to the batch's arrival at a subscriber
of another session: what any fleet node sees), then with a ``formation ros2`` process (latency
from the same put to the arrival of the first and of the last robot's ``/<id>/odom``: the
bridge translates the batch robot by robot). The bridge's CPU (user + system, % of one core)
and the router's in each window.

Backend: ``Ros2Backend.apply`` (what the agent's motor worker calls right after a firmware tick)
to the twist's arrival at a ROS 2 base's ``cmd_vel`` subscriber in another session through a
router (the simulated base of the tests), next to a plain put of 52 bytes on the same path.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bus_schemas.ros2 import msgs, rmw


def _samples() -> dict[str, Any]:
    header = msgs.Header(msgs.Time(12, 345), "odom")
    pose = msgs.Pose(msgs.Point(1.0, 2.0), msgs.quaternion_from_yaw(0.3))
    return {
        "geometry_msgs/msg/Twist": msgs.Twist(msgs.Vector3(0.2), msgs.Vector3(z=0.5)),
        "nav_msgs/msg/Odometry": msgs.Odometry(
            header, "base_link", msgs.PoseWithCovariance(pose, tuple(float(i) for i in range(36)))
        ),
        "tf2_msgs/msg/TFMessage": msgs.TFMessage(
            tuple(
                msgs.TransformStamped(
                    header, f"r{k}/base_link", msgs.Transform(msgs.Vector3(1.0), pose.orientation)
                )
                for k in range(10)
            )
        ),
        "geometry_msgs/msg/PoseArray": msgs.PoseArray(header, (pose,) * 10),
    }


def _best_us(fn: Any, n: int = 2000, rounds: int = 15) -> float:
    best = float("inf")
    for _ in range(rounds):
        t0 = time.process_time()
        for _ in range(n):
            fn()
        best = min(best, (time.process_time() - t0) / n)
    return best * 1e6


def codec_table() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))
    import ros2_reference as ref

    ts = ref.typestore()
    print(f"{'type':32} {'enc ours':>9} {'enc rosbags':>11} {'dec ours':>9} {'dec rosbags':>11}")
    for name, msg in _samples().items():
        ours = msgs.encode(msg)
        theirs_obj = ref.to_rosbags(msg, name)
        assert bytes(ts.serialize_cdr(theirs_obj, name)) == ours
        cls = type(msg)
        enc_ours = _best_us(lambda msg=msg: msgs.encode(msg))
        enc_ref = _best_us(lambda o=theirs_obj, name=name: ts.serialize_cdr(o, name))
        dec_ours = _best_us(lambda b=ours, cls=cls: msgs.decode(b, cls))
        dec_ref = _best_us(lambda b=ours, name=name: ts.deserialize_cdr(b, name))
        print(
            f"{name:32} {enc_ours:8.1f}u {enc_ref:10.1f}u {dec_ours:8.1f}u {dec_ref:10.1f}u"
            f"   ({len(ours)} B)"
        )


def bridge_latency(count: int) -> None:
    import zenoh
    from common import LatencyStats, print_latency, print_latency_header, router, running

    from bus_schemas import Pose, encode, keys

    with router() as endpoint:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        with zenoh.open(conf) as s:
            # baseline: the same put -> callback through the router, no bridge
            sent: dict[int, float] = {}
            lat: list[float] = []
            done = threading.Event()

            def on_plain(sample: zenoh.Sample) -> None:
                k = int.from_bytes(sample.payload.to_bytes()[:4], "little")
                lat.append(time.monotonic() - sent[k])
                if len(lat) >= count:
                    done.set()

            sub = s.declare_subscriber("bench/plain", on_plain)
            time.sleep(0.3)
            for k in range(count):
                sent[k] = time.monotonic()
                s.put("bench/plain", k.to_bytes(4, "little") + bytes(96))
                time.sleep(0.01)
            done.wait(10.0)
            sub.undeclare()
            base = LatencyStats.from_samples(lat, count - len(lat))

            argv = [sys.executable, "-m", "formation", "ros2", "--endpoint", endpoint]
            with running([*argv, "--fleet", "bench"], ready="ros2 bridge ready"):
                odom_key = rmw.topic_key(0, "/r1/odom", msgs.ros_type(msgs.Odometry))
                sent2: dict[int, float] = {}
                lat2: list[float] = []
                done2 = threading.Event()

                def on_odom(sample: zenoh.Sample) -> None:
                    odom = msgs.decode(sample.payload.to_bytes(), msgs.Odometry)
                    if isinstance(odom, msgs.Odometry):
                        k = round(odom.pose.pose.position.x * 1000)
                        if k in sent2:
                            lat2.append(time.monotonic() - sent2.pop(k))
                    if len(lat2) >= count:
                        done2.set()

                sub2 = s.declare_subscriber(odom_key, on_odom)
                time.sleep(0.5)
                for k in range(1, count + 1):
                    pose = Pose(t=0.01 * k, seq=k, x=k / 1000, y=0.0, theta=0.0)
                    sent2[k] = time.monotonic()
                    s.put(keys.pose_key("bench", "r1"), encode(pose))
                    time.sleep(0.01)
                done2.wait(10.0)
                sub2.undeclare()
                bridged = LatencyStats.from_samples(lat2, count - len(lat2))
    print_latency_header()
    print_latency("put -> subscriber (no bridge)", base)
    print_latency("bus pose -> /r1/odom (bridge)", bridged, base)


class _Arrivals:
    """Arrival times of frame ``k`` (carried in ``y`` = k/1000) on one subscription."""

    def __init__(self, decode_y: Any) -> None:
        self.decode_y = decode_y
        self.sent: dict[int, float] = {}
        self.lat: list[float] = []
        self.lock = threading.Lock()

    def __call__(self, sample: Any) -> None:
        now = time.monotonic()
        y = self.decode_y(sample.payload.to_bytes())
        if y is None:
            return
        with self.lock:
            t0 = self.sent.get(round(y * 1000))
            if t0 is not None:
                self.lat.append(now - t0)


def _poses_y(data: bytes) -> float | None:
    from bus_schemas import PoseBatch, decode

    batch = decode(data, PoseBatch)
    return batch.y[0] if isinstance(batch, PoseBatch) else None


def _odom_y(data: bytes) -> float | None:
    odom = msgs.decode(data, msgs.Odometry)
    return odom.pose.pose.position.y if isinstance(odom, msgs.Odometry) else None


def _stream(s: Any, ids: tuple[str, ...], window_s: float, probes: list[_Arrivals]) -> float:
    """Publish ``poses`` batches at 30 Hz for ``window_s`` (after a 0.5 s warm-up), noting each
    frame's send time in ``probes``; returns the measured window (s)."""
    from bus_schemas import keys

    key = keys.poses_key("bench")
    for k in range(1, 16):  # warm up: publishers declared, tokens out
        s.put(key, _frame(k, ids))
        time.sleep(1 / 30)
    t0 = time.monotonic()
    k = 16
    while time.monotonic() - t0 < window_s:
        sent = time.monotonic()
        for p in probes:
            with p.lock:
                p.sent[k] = sent
        s.put(key, _frame(k, ids))
        k += 1
        time.sleep(max(0.0, t0 + (k - 16) / 30 - time.monotonic()))
    time.sleep(0.3)  # the last frames arrive
    return time.monotonic() - t0


def bridge_load(counts: list[int], window_s: float = 10.0) -> None:
    """The bridge's CPU and the latency it adds, N robots' poses at 30 Hz, beside the same run
    without it (same router, same publisher, one process each)."""
    import zenoh
    from common import LatencyStats, cpu_s, router, running

    rows: list[tuple[int, str, LatencyStats, float, float]] = []
    for n in counts:
        ids = tuple(f"r{k + 1}" for k in range(n))
        with router() as endpoint:
            conf = zenoh.Config()
            conf.insert_json5("mode", '"client"')
            conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
            conf.insert_json5("scouting/multicast/enabled", "false")
            router_pid = _pid_listening(endpoint)
            with zenoh.open(conf) as pub, zenoh.open(conf) as sub_s:
                # without the bridge: the batch itself at a subscriber (what a fleet node sees)
                from bus_schemas import keys

                plain = _Arrivals(_poses_y)
                sub = sub_s.declare_subscriber(keys.poses_key("bench"), plain)
                time.sleep(0.3)
                r0 = cpu_s(router_pid)
                dt = _stream(pub, ids, window_s, [plain])
                rows.append((n, "poses batch, no bridge", LatencyStats.from_samples(plain.lat),
                             math.nan, 100 * (cpu_s(router_pid) - r0) / dt))  # fmt: skip
                sub.undeclare()
                argv = [sys.executable, "-m", "formation", "ros2", "--endpoint", endpoint]
                with running([*argv, "--fleet", "bench"], ready="ros2 bridge ready") as bridge:
                    first, last = _Arrivals(_odom_y), _Arrivals(_odom_y)
                    odom_t = msgs.ros_type(msgs.Odometry)
                    subs = [
                        sub_s.declare_subscriber(rmw.topic_key(0, f"/{rid}/odom", odom_t), p)
                        for rid, p in ((ids[0], first), (ids[-1], last))
                    ]
                    time.sleep(0.5)
                    c0, r0 = cpu_s(bridge.pid), cpu_s(router_pid)
                    dt = _stream(pub, ids, window_s, [first, last])
                    bridge_cpu = 100 * (cpu_s(bridge.pid) - c0) / dt
                    router_cpu = 100 * (cpu_s(router_pid) - r0) / dt
                    for sub in subs:
                        sub.undeclare()
                rows.append((n, f"/{ids[0]}/odom (bridge)", LatencyStats.from_samples(first.lat),
                             bridge_cpu, router_cpu))  # fmt: skip
                rows.append((n, f"/{ids[-1]}/odom (bridge)", LatencyStats.from_samples(last.lat),
                             bridge_cpu, router_cpu))  # fmt: skip
    print(
        f"{'robots':>6} {'path':28} {'n':>5} {'p50 ms':>7} {'p99 ms':>7} "
        f"{'bridge CPU':>10} {'router CPU':>10}"
    )
    for n, what, st, bcpu, rcpu in rows:
        b = "-" if math.isnan(bcpu) else f"{bcpu:.1f}%"
        print(
            f"{n:6d} {what:28} {st.n:5d} {st.p50_us / 1e3:7.2f} {st.p99_us / 1e3:7.2f} "
            f"{b:>10} {rcpu:9.1f}%"
        )


def backend_latency(count: int) -> None:
    import zenoh
    from common import LatencyStats, print_latency, print_latency_header, router

    import runtime as rt
    from robot_agent.core.kinematics import twist_from_wheels
    from robot_agent.core.params import RobotGeometry
    from robot_agent.motors.ros2 import Ros2Backend, Ros2MotorConfig

    geom = RobotGeometry(wheel_radius_m=0.033, half_track_m=0.08)
    with router() as endpoint:
        settings = rt.ZenohSettings(connect=(endpoint,))
        base = rt.open_session(settings)
        sent: dict[float, float] = {}
        lat: list[float] = []
        cmd_key = rmw.topic_key(0, "/cmd_vel", msgs.ros_type(msgs.Twist))

        def on_cmd(sample: zenoh.Sample) -> None:
            tw = msgs.decode(sample.payload.to_bytes(), msgs.Twist)
            if isinstance(tw, msgs.Twist) and tw.linear.x in sent:
                lat.append(time.monotonic() - sent.pop(tw.linear.x))

        sub = base.declare_subscriber(cmd_key, on_cmd)
        plain = rt.open_session(settings)
        time.sleep(0.3)
        for k in range(1, count + 1):  # the floor: a plain 52-byte put on the same key
            payload = msgs.encode(msgs.Twist(msgs.Vector3(x=k * 1e-4)))
            sent[k * 1e-4] = time.monotonic()
            plain.put(cmd_key, payload)
            time.sleep(0.01)
        time.sleep(0.3)
        floor = LatencyStats.from_samples(lat, count - len(lat))
        lat.clear()
        sent.clear()
        backend = Ros2Backend(
            Ros2MotorConfig(endpoint=endpoint, mode="client"),
            geom,
            subscribe=rt.subscribe_on_thread,
        )
        backend.open()
        time.sleep(0.3)
        for k in range(1, count + 1):
            w = k * 1e-4 / geom.wheel_radius_m  # both wheels: v = k * 1e-4 m/s exactly
            v, _ = twist_from_wheels(w, w, geom)
            sent[v] = time.monotonic()
            backend.apply(w, w, float(k))
            time.sleep(0.01)
        time.sleep(0.3)
        backend.close()
        via = LatencyStats.from_samples(lat, count - len(lat))
        sub.undeclare()
        for s in (base, plain):
            rt.close_session(s)
    print_latency_header()
    print_latency("plain put -> cmd_vel subscriber", floor)
    print_latency("Ros2Backend.apply -> base cmd_vel", via, floor)


def _frame(k: int, ids: tuple[str, ...]) -> bytes:
    """Frame ``k`` of a ``poses`` batch of robots ``ids`` (30 Hz, all moving along x)."""
    from bus_schemas import PoseBatch, encode

    n = len(ids)
    xs = tuple(0.01 * k + 0.1 * i for i in range(n))
    zeros = (0.0,) * n
    ys = (k / 1000,) * n  # the frame number, read back from the odometry
    batch = PoseBatch(t=k / 30, seq=k, robots=ids, x=xs, y=ys, theta=zeros, stamp=k / 30)
    return encode(batch)


def _pid_listening(endpoint: str) -> int:
    """The pid of the `formation router` serving ``endpoint`` (this process's child)."""
    import os

    port = endpoint.rsplit(":", 1)[1]
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"router" in cmd and any(port.encode() in c for c in cmd):
            return int(entry.name)
    raise RuntimeError(f"no router process for {endpoint}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--bridge", type=int, default=0, metavar="N", help="bridge latency samples")
    p.add_argument(
        "--cpu", default="", metavar="N,M", help="bridge CPU and added latency at these sizes"
    )
    p.add_argument("--window", type=float, default=10.0, help="--cpu: seconds per measurement")
    p.add_argument("--backend", type=int, default=0, metavar="N", help="backend latency samples")
    ns = p.parse_args()
    codec_table()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    if ns.bridge:
        bridge_latency(ns.bridge)
    if ns.cpu:
        bridge_load([int(x) for x in ns.cpu.split(",")], ns.window)
    if ns.backend:
        backend_latency(ns.backend)
    return 0


if __name__ == "__main__":
    sys.exit(main())
