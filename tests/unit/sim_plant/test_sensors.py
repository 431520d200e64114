"""Tests of sim_plant.core.sensors: camera frame clock, latency, noise; link delay and loss."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_plant.core.sensors import Camera, CommandLink


def ticks(t_end_s: float, dt_s: float) -> list[float]:
    """Sim times 0, dt, 2 dt, ... up to t_end inclusive, as a lockstep loop would produce."""
    return [k * dt_s for k in range(round(t_end_s / dt_s) + 1)]


def truth_at(t_s: float, n: int = 2) -> np.ndarray:
    """A moving fleet: robot i at (i + 0.1 t, -0.2 t), heading 0.5 t."""
    i = np.arange(n, dtype=np.float64)
    return np.column_stack([i + 0.1 * t_s, np.full(n, -0.2 * t_s), np.full(n, 0.5 * t_s)])


# ---------------------------------------------------------------- camera


def test_camera_frame_count_in_one_second() -> None:
    cam = Camera(2, rate_hz=30.0, pos_std_m=0.0, theta_std_rad=0.0, latency_s=0.0)
    taken = [t for t in ticks(1.0, 0.001) if cam.capture(t, truth_at(t))]
    # Frames at k/30 for k = 0..30 within [0, 1]: 30 in [0, 1) plus the one at t = 1.
    assert len(taken) == 31
    assert sum(t < 1.0 - 1e-9 for t in taken) == 30
    assert cam.frames_taken == 31 and cam.frames_missed == 0
    np.testing.assert_allclose(taken, np.arange(31) / 30.0, atol=0.001)


def test_camera_rate_with_non_dividing_tick() -> None:
    cam = Camera(1, rate_hz=30.0, pos_std_m=0.0, theta_std_rad=0.0)
    n_frames = sum(cam.capture(t, truth_at(t, 1)) for t in ticks(10.0, 0.007))
    assert n_frames == 301  # k = 0..300
    assert cam.frames_missed == 0


def test_camera_coarse_ticks_miss_frames() -> None:
    cam = Camera(1, rate_hz=30.0, pos_std_m=0.0, theta_std_rad=0.0)
    n_frames = sum(cam.capture(t, truth_at(t, 1)) for t in ticks(1.0, 0.1))
    assert n_frames == 11
    assert n_frames + cam.frames_missed == 31


def test_camera_latency_and_stamp() -> None:
    dt = 1.0 / 300.0  # divides the frame period: stamps land exactly on k / 30
    latency = 0.05
    cam = Camera(3, rate_hz=30.0, pos_std_m=0.0, theta_std_rad=0.0, latency_s=latency)
    got: list[tuple[float, int, float, float, float, float]] = []
    for t in ticks(2.0, dt):
        cam.capture(t, truth_at(t, 3))
        got.extend((t, *m) for m in cam.poll(t))
    assert got, "no measurement delivered"
    stamps = sorted({g[2] for g in got})
    np.testing.assert_allclose(stamps, np.arange(len(stamps)) / 30.0, atol=1e-9)
    for t_rx, i, stamp, x, y, th in got:
        assert latency - 1e-9 <= t_rx - stamp < latency + dt
        # Noise-free: the measurement is the truth at the stamp.
        np.testing.assert_allclose([x, y, th], truth_at(stamp, 3)[i], atol=1e-12)
    # Each frame delivers all three robots, in id order.
    assert [g[1] for g in got[:6]] == [0, 1, 2, 0, 1, 2]
    # Frames exposed in the last 50 ms are still in flight.
    assert cam.in_flight == 2


def test_camera_poll_before_latency_returns_nothing() -> None:
    cam = Camera(1, pos_std_m=0.0, theta_std_rad=0.0, latency_s=0.03)
    assert cam.capture(0.0, truth_at(0.0, 1))
    assert cam.poll(0.029) == []
    out = cam.poll(0.030)
    assert len(out) == 1 and out[0][1] == 0.0
    assert cam.poll(1.0) == []


def test_camera_noise_std_and_wrap() -> None:
    n = 500
    rng = np.random.default_rng(12345)
    cam = Camera(n, rate_hz=30.0, pos_std_m=0.003, theta_std_rad=0.01, latency_s=0.0, rng=rng)
    truth = np.column_stack([np.zeros(n), np.ones(n), np.full(n, math.pi - 0.005)])
    errs = []
    for k in range(40):
        t = k / 30.0
        assert cam.capture(t, truth)
        for frame in cam.poll_frames(t):
            errs.append(frame.poses - truth[frame.ids])
            assert np.all(frame.poses[:, 2] > -math.pi) and np.all(frame.poses[:, 2] <= math.pi)
    e = np.concatenate(errs)
    e[:, 2] = (e[:, 2] + math.pi) % (2.0 * math.pi) - math.pi  # undo the wrap near +-pi
    assert e.shape == (40 * n, 3)
    # 20000 samples: the sample std is within ~1 % of the true one; allow 5 %.
    assert np.std(e[:, 0]) == pytest.approx(0.003, rel=0.05)
    assert np.std(e[:, 1]) == pytest.approx(0.003, rel=0.05)
    assert np.std(e[:, 2]) == pytest.approx(0.01, rel=0.05)
    assert abs(np.mean(e[:, 0])) < 0.003 * 5 / math.sqrt(e.shape[0])
    # Some heading measurements crossed +pi and were wrapped to near -pi.
    assert np.any(truth[0, 2] + e[:, 2] > math.pi)


def _camera_run(seed: int) -> list[tuple[int, float, float, float, float]]:
    cam = Camera(
        4,
        rng=np.random.default_rng(seed),
        frame_drop_prob=0.1,
        miss_prob=0.1,
    )
    out = []
    for t in ticks(1.0, 0.01):
        cam.capture(t, truth_at(t, 4))
        out.extend(cam.poll(t))
    return out


def test_camera_deterministic_for_a_seed() -> None:
    a, b, c = _camera_run(3), _camera_run(3), _camera_run(4)
    assert a == b
    assert a != c


def test_camera_dropout_rates() -> None:
    rng = np.random.default_rng(99)
    n = 10
    cam = Camera(n, pos_std_m=0.0, theta_std_rad=0.0, rng=rng, frame_drop_prob=0.2, miss_prob=0.1)
    truth = np.zeros((n, 3))
    for k in range(3000):
        cam.capture(k / 30.0, truth)
    delivered = sum(len(f.ids) for f in cam.poll_frames(1e9))
    assert cam.frames_taken == 3000
    # Binomial(3000, 0.2): std 22; allow ~4 std.
    assert abs(cam.frames_dropped - 600) < 90
    kept = (cam.frames_taken - cam.frames_dropped) * n
    assert cam.measurements_missed / kept == pytest.approx(0.1, abs=0.015)
    assert delivered == kept - cam.measurements_missed == cam.measurements_delivered


def test_camera_validation() -> None:
    with pytest.raises(ValueError):
        Camera(2)  # noise configured but no rng
    with pytest.raises(ValueError):
        Camera(2, rate_hz=0.0, pos_std_m=0.0, theta_std_rad=0.0)
    with pytest.raises(ValueError):
        Camera(2, pos_std_m=0.0, theta_std_rad=0.0, frame_drop_prob=1.5)
    cam = Camera(2, pos_std_m=0.0, theta_std_rad=0.0)
    with pytest.raises(ValueError):
        cam.capture(0.0, np.zeros((3, 3)))
    cam.resize(3)
    assert cam.capture(0.0, np.zeros((3, 3)))


def test_camera_thousand_robots() -> None:
    n = 1000
    cam = Camera(n, rng=np.random.default_rng(0))
    truth = np.zeros((n, 3))
    cam.capture(0.0, truth)
    out = cam.poll(0.03)
    assert len(out) == n
    assert [m[0] for m in out] == list(range(n))


# ---------------------------------------------------------------- command link


def test_link_fixed_latency() -> None:
    link: CommandLink[str] = CommandLink(latency_s=0.01)
    assert link.send(1.0, 0, "a") == pytest.approx(1.01)
    assert link.poll(1.009) == []
    assert link.poll(1.01) == [(0, "a")]
    assert (link.sent, link.dropped, link.delivered, link.in_flight) == (1, 0, 1, 0)


def test_link_jitter_distribution() -> None:
    rng = np.random.default_rng(2024)
    lat, jit = 0.01, 0.02
    link: CommandLink[int] = CommandLink(latency_s=lat, jitter_s=jit, rng=rng, fifo=False)
    delays = []
    for k in range(5000):
        d = link.send(0.0, k % 7, k)
        assert d is not None
        delays.append(d)
    arr = np.asarray(delays)
    assert arr.min() >= lat and arr.max() < lat + jit
    assert arr.mean() == pytest.approx(lat + jit / 2.0, abs=0.0005)  # std of mean 8e-5
    assert np.std(arr) == pytest.approx(jit / math.sqrt(12.0), rel=0.05)
    out = link.poll(1.0)
    assert len(out) == 5000 and link.delivered == 5000
    # Poll order is delivery order.
    order = [cmd for _, cmd in out]
    np.testing.assert_array_equal(arr[order], np.sort(arr))


def test_link_loss_rate_and_counters() -> None:
    rng = np.random.default_rng(5)
    link: CommandLink[int] = CommandLink(latency_s=0.01, loss_prob=0.2, rng=rng)
    for k in range(10000):
        link.send(k * 0.001, 0, k)
    # Binomial(10000, 0.2): std 40.
    assert abs(link.dropped - 2000) < 160
    delivered = link.poll(5.0)
    assert link.sent == link.dropped + link.delivered + link.in_flight
    assert link.in_flight > 0  # the last 10 ms are still in the air
    delivered += link.poll(100.0)
    assert link.delivered == len(delivered) == 10000 - link.dropped


def test_link_fifo_per_robot_even_with_jitter() -> None:
    rng = np.random.default_rng(11)
    link: CommandLink[int] = CommandLink(latency_s=0.005, jitter_s=0.05, rng=rng, fifo=True)
    for k in range(2000):
        link.send(k * 0.001, k % 3, k)
    got: list[tuple[int, int]] = []
    for k in range(3000):
        got.extend(link.poll(k * 0.001))
    assert len(got) == 2000
    for robot in range(3):
        seq = [cmd for i, cmd in got if i == robot]
        assert seq == sorted(seq)
        assert seq == list(range(robot, 2000, 3))


def test_link_without_fifo_can_reorder() -> None:
    rng = np.random.default_rng(11)
    link: CommandLink[int] = CommandLink(latency_s=0.005, jitter_s=0.05, rng=rng, fifo=False)
    for k in range(200):
        link.send(k * 0.001, 0, k)
    seq = [cmd for _, cmd in link.poll(10.0)]
    assert sorted(seq) == list(range(200))
    assert seq != sorted(seq)


def test_link_ties_in_send_order_and_determinism() -> None:
    link: CommandLink[str] = CommandLink(latency_s=0.02)
    link.send(0.0, 2, "x")
    link.send(0.0, 1, "y")
    link.send(0.0, 2, "z")
    assert link.poll(0.02) == [(2, "x"), (1, "y"), (2, "z")]

    def run(seed: int) -> list[tuple[int, int]]:
        lk: CommandLink[int] = CommandLink(0.01, 0.01, 0.3, np.random.default_rng(seed))
        for k in range(100):
            lk.send(k * 0.002, k % 4, k)
        return lk.poll(1.0)

    assert run(1) == run(1)
    assert run(1) != run(2)


def test_link_validation() -> None:
    with pytest.raises(ValueError):
        CommandLink(jitter_s=0.01)  # randomness without rng
    with pytest.raises(ValueError):
        CommandLink(latency_s=-0.1)
    with pytest.raises(ValueError):
        CommandLink(loss_prob=2.0, rng=np.random.default_rng(0))
    link: CommandLink[None] = CommandLink()
    with pytest.raises(ValueError):
        link.send(math.nan, 0, None)
    assert link.sent == 0
