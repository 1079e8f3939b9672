"""TfBuffer: hand-computed interpolation, chains, inverses, static timelessness, failures, mounts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ltmap_cli.errors import InputError, TransformError
from ltmap_cli.io.frames import OdometrySample, TfSample
from ltmap_cli.io.transforms import LookupFailure, TfBuffer, choose_fixed_frame, parse_mount, rpy_to_quat

S = 1_000_000_000


def yaw_q(yaw):
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def yaw_of(m):
    return math.atan2(m[1, 0], m[0, 0])


def test_translation_midpoint_and_slerp_half_of_90_degrees():
    b = TfBuffer()
    b.add(TfSample(0, "odom", "base_link", (0.0, 0.0, 0.0), yaw_q(0.0)))
    b.add(TfSample(10 * S, "odom", "base_link", (2.0, 4.0, 0.0), yaw_q(math.pi / 2)))
    m = b.lookup("odom", "base_link", 5 * S)
    assert m.dtype == np.float64 and m.shape == (4, 4)
    np.testing.assert_allclose(m[:3, 3], [1.0, 2.0, 0.0], atol=1e-12)
    assert yaw_of(m) == pytest.approx(math.pi / 4, abs=1e-12)
    # at 1/4: translation (0.5, 1.0), yaw 22.5 degrees (SLERP is linear in angle)
    m = b.lookup("odom", "base_link", int(2.5 * S))
    np.testing.assert_allclose(m[:3, 3], [0.5, 1.0, 0.0], atol=1e-12)
    assert yaw_of(m) == pytest.approx(math.pi / 8, abs=1e-12)


def test_exact_stamps_and_no_extrapolation():
    b = TfBuffer()
    b.add(TfSample(1 * S, "odom", "base_link", (1.0, 0.0, 0.0), yaw_q(0)))
    b.add(TfSample(2 * S, "odom", "base_link", (3.0, 0.0, 0.0), yaw_q(0)))
    assert b.lookup("odom", "base_link", 1 * S)[0, 3] == 1.0
    assert b.lookup("odom", "base_link", 2 * S)[0, 3] == 3.0
    with pytest.raises(LookupFailure) as e:
        b.lookup("odom", "base_link", 2 * S + 1)
    assert "odom -> base_link" in e.value.reason and "after its last sample" in e.value.reason
    assert isinstance(e.value, TransformError)
    m, why = b.try_lookup("odom", "base_link", S - 1)
    assert m is None and "before its first sample" in why
    tol = TfBuffer(tolerance_ns=10)
    tol.add(TfSample(1 * S, "odom", "base_link", (1.0, 0.0, 0.0), yaw_q(0)))
    assert tol.lookup("odom", "base_link", S + 10)[0, 3] == 1.0
    assert tol.try_lookup("odom", "base_link", S + 11)[0] is None


def test_chain_of_three_edges_and_inverse_direction():
    b = TfBuffer()
    b.add(TfSample(0, "map", "odom", (1.0, 0.0, 0.0), yaw_q(math.pi / 2), static=True))
    b.add(TfSample(0, "odom", "base_link", (0.0, 2.0, 0.0), yaw_q(0.0)))
    b.add(TfSample(10 * S, "odom", "base_link", (0.0, 2.0, 0.0), yaw_q(0.0)))
    b.add(TfSample(0, "base_link", "laser", (0.5, 0.0, 0.2), yaw_q(0.0), static=True))
    m = b.lookup("map", "laser", 5 * S)
    # laser origin: (0.5, 2, 0.2) in odom; odom is rotated 90 deg and moved (1, 0) in map:
    # (x, y) -> (1 - y, x) = (1 - 2, 0.5) = (-1, 0.5)
    np.testing.assert_allclose(m @ [0, 0, 0, 1], [-1.0, 0.5, 0.2, 1.0], atol=1e-12)
    # a point 1 m ahead of the laser is 1 m along map +y
    np.testing.assert_allclose(m @ [1, 0, 0, 1], [-1.0, 1.5, 0.2, 1.0], atol=1e-12)
    inv = b.lookup("laser", "map", 5 * S)
    np.testing.assert_allclose(inv @ m, np.eye(4), atol=1e-12)
    # between siblings: laser and another child of base_link
    b.add(TfSample(0, "base_link", "camera", (0.0, 0.5, 0.0), yaw_q(0.0), static=True))
    np.testing.assert_allclose(b.lookup("camera", "laser", 5 * S)[:3, 3], [0.5, -0.5, 0.2], atol=1e-12)


def test_static_is_timeless_and_slashes_are_one_frame():
    b = TfBuffer()
    # stamped 4 hours before the log, as in the comprobo22 bag
    b.add(TfSample(5 * S, "/base_link", "/rplidar_link", (0.1, 0.0, 0.3), yaw_q(math.pi), static=True))
    b.add(TfSample(4 * 3600 * S, "odom", "base_link", (1.0, 0.0, 0.0), yaw_q(0)))
    m = b.lookup("/odom", "rplidar_link", 4 * 3600 * S)
    np.testing.assert_allclose(m[:3, 3], [1.1, 0.0, 0.3], atol=1e-12)
    assert yaw_of(m) == pytest.approx(math.pi, abs=1e-12)
    assert b.frames == {"odom", "base_link", "rplidar_link"}


def test_missing_edge_reasons_name_the_edge_and_the_fix():
    b = TfBuffer()
    b.add(TfSample(0, "odom", "base_link", (0, 0, 0), yaw_q(0)))
    m, why = b.try_lookup("odom", "laser", 0)
    assert m is None
    assert why == ("no transform base_link -> laser: frame laser is not in tf; give its mount with "
                   "--tf base_link:laser=x,y,z,roll,pitch,yaw")
    b.add(TfSample(0, "imu_base", "imu", (0, 0, 0), yaw_q(0), static=True))
    with pytest.raises(LookupFailure, match=r"no transform odom -> imu: .*--tf odom:imu_base="):
        b.lookup("odom", "imu", 0)
    assert b.connection_problem("odom", "imu").startswith("no transform odom -> imu")
    assert b.connection_problem("odom", "base_link") is None


def test_mount_parsing_and_override():
    s = parse_mount("base_link:/laser=0.1,0,0.2,0,0,1.5707963267948966")
    assert (s.parent, s.child, s.static) == ("base_link", "laser", True)
    assert s.translation == (0.1, 0.0, 0.2)
    np.testing.assert_allclose(s.rotation_xyzw, yaw_q(math.pi / 2), atol=1e-12)
    for bad in ["base_link:laser=1,2,3", "base_link-laser=1,2,3,4,5,6", "a:b=1,2,3,4,5,x", "a:a=0,0,0,0,0,0", ""]:
        with pytest.raises(InputError, match=r"parent:child=x,y,z,roll,pitch,yaw"):
            parse_mount(bad)
    b = TfBuffer()
    b.add(TfSample(0, "base_link", "laser", (9.0, 9.0, 9.0), yaw_q(0), static=True))
    b.add_mount("base_link:laser=1,0,0,0,0,0")
    b.add(TfSample(0, "base_link", "laser", (9.0, 9.0, 9.0), yaw_q(0), static=True))  # log again: ignored
    assert b.lookup("base_link", "laser", 123)[0, 3] == 1.0
    assert b.ignored["base_link -> laser from static"] == 1


def test_rpy_matches_ros_convention():
    # roll 90 deg then yaw 90 deg (fixed axes): x axis -> +y, z axis -> +x
    q = np.array(rpy_to_quat(math.pi / 2, 0.0, math.pi / 2))
    b = TfBuffer()
    b.add(TfSample(0, "a", "b", (0, 0, 0), tuple(q), static=True))
    m = b.lookup("a", "b", 0)
    np.testing.assert_allclose(m[:3, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(m[:3, 2], [1, 0, 0], atol=1e-12)


def test_odometry_yields_to_tf_in_either_order_and_fixed_frame():
    b = TfBuffer()
    b.add(OdometrySample(0, "odom", "base_link", (5.0, 0, 0), yaw_q(0)))
    b.add(TfSample(0, "odom", "base_link", (1.0, 0, 0), yaw_q(0)))
    b.add(OdometrySample(0, "odom", "base_link", (5.0, 0, 0), yaw_q(0)))
    assert b.lookup("odom", "base_link", 0)[0, 3] == 1.0
    assert b.fixed_frame() == "odom"
    b.add(TfSample(0, "map", "odom", (0, 0, 0), yaw_q(0)))
    assert b.fixed_frame() == "map"
    assert b.fixed_frame("/odom") == "odom"
    with pytest.raises(TransformError, match="--fixed-frame world"):
        b.fixed_frame("world")
    with pytest.raises(TransformError, match="neither map nor odom"):
        choose_fixed_frame({"base_link", "laser"})
    assert b.tree_text().splitlines() == ["map", "  odom  [tf, 1 samples]", "    base_link  [tf, 1 samples]"]


def test_memory_is_bounded_by_the_window():
    b = TfBuffer(window_ns=1 * S)
    for i in range(1000):
        b.add(TfSample(i * S // 100, "odom", "base_link", (i / 100, 0, 0), yaw_q(0)))
    n = len(b.edges["base_link"].times)
    assert n < 400  # 10 s of 100 Hz samples, window 1 s: at most ~3 windows kept
    assert b.lookup("odom", "base_link", 9 * S + S // 2)[0, 3] == pytest.approx(9.5)


def test_available_until_tells_when_a_frame_can_be_placed():
    b = TfBuffer()
    assert b.available_until("odom", "laser") is None
    b.add(TfSample(0, "base_link", "laser", (0, 0, 0), yaw_q(0), static=True))
    assert b.available_until("base_link", "laser") == 2**63 - 1
    b.add(TfSample(1 * S, "odom", "base_link", (0, 0, 0), yaw_q(0)))
    b.add(TfSample(3 * S, "odom", "base_link", (0, 0, 0), yaw_q(0)))
    b.add(TfSample(2 * S, "map", "odom", (0, 0, 0), yaw_q(0)))
    assert b.available_until("odom", "laser") == 3 * S
    assert b.available_until("map", "laser") == 2 * S


def test_lookup_caches_follow_new_samples_mounts_and_reparenting():
    """The chain and per-edge matrix caches never serve a stale answer: every lookup below equals
    the same lookup on a fresh buffer that holds the same samples and has no cache history."""
    samples = []
    b = TfBuffer(tolerance_ns=S // 20)

    def add(sample):
        samples.append(sample)
        b.add(sample)

    def fresh(stamp, target="map", source="laser"):
        f = TfBuffer(tolerance_ns=S // 20)
        for s in samples:
            f.add(s)
        for spec in mounts:
            f.add_mount(spec)
        return f.lookup(target, source, stamp)

    mounts = []
    add(TfSample(0, "map", "odom", (0.0, 0.0, 0.0), yaw_q(0.0)))
    add(TfSample(0, "odom", "base_link", (0.0, 0.0, 0.0), yaw_q(0.0)))
    add(TfSample(S, "odom", "base_link", (1.0, 0.0, 0.0), yaw_q(0.0)))
    add(TfSample(0, "base_link", "laser", (0.5, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), static=True))
    add(TfSample(2 * S, "map", "odom", (0.0, 0.0, 0.0), yaw_q(0.0)))
    t = S + S // 50  # 20 ms after odom's last sample: within the tolerance, the last sample is used
    first = b.lookup("map", "laser", t)
    np.testing.assert_allclose(first[:3, 3], [1.5, 0.0, 0.0], atol=1e-12)
    assert np.array_equal(b.lookup("map", "laser", t), first)  # served from the cache
    # a newer odom sample: the same stamp now interpolates (1.0 -> 3.0 over 1 s, 2 % of the way)
    add(TfSample(2 * S, "odom", "base_link", (3.0, 0.0, 0.0), yaw_q(0.0)))
    second = b.lookup("map", "laser", t)
    np.testing.assert_allclose(second[:3, 3], [1.54, 0.0, 0.0], atol=1e-12)
    assert np.array_equal(second, fresh(t))
    # a user mount replaces the static laser edge
    mounts.append("base_link:laser=0,0.2,0,0,0,0")
    b.add_mount(mounts[-1])
    third = b.lookup("map", "laser", t)
    np.testing.assert_allclose(third[:3, 3], [1.04, 0.2, 0.0], atol=1e-12)
    assert np.array_equal(third, fresh(t))
    # the same source re-parents the laser: the cached chain laser -> base_link is dropped
    mounts.append("odom:laser=0,0,1,0,0,0")
    b.add_mount(mounts[-1])
    fourth = b.lookup("map", "laser", t)
    np.testing.assert_allclose(fourth[:3, 3], [0.0, 0.0, 1.0], atol=1e-12)
    assert np.array_equal(fourth, fresh(t))
    # the returned matrices are the caller's own: changing one does not change the next lookup
    fourth[0, 3] = 99.0
    assert b.lookup("map", "laser", t)[0, 3] == 0.0


def test_a_cycle_in_recorded_tf_ends_a_frames_chain():
    """a -> b and b -> a both recorded (a broken tf tree): the chain from a frame to its root,
    which the localization pre-pass walks too, stops instead of looping."""
    from ltmap_cli.io.transforms import TfBuffer

    tf = TfBuffer()
    tf.add_mount("b:a=1,0,0,0,0,0")
    tf.add_mount("a:b=0,1,0,0,0,0")
    tf.add_mount("a:laser=0,0,0.3,0,0,0")
    assert tf.chain("laser") == ("laser", "a", "b")
    assert tf.root("/laser") == "b"


def test_no_fixed_frame_reason_without_any_sensor_frame():
    """A log cut before its first sensor message (found by the reader fuzz): tf has a tree but no
    sensor frame is known; the line names tf's root, and does not fail."""
    from ltmap_cli.io.transforms import no_fixed_frame_reason

    text = no_fixed_frame_reason({"base_link", "laser"}, [], {}, ["base_link"])
    assert "--fixed-frame base_link (the root of tf" in text and "--tf odom:base_link=" in text


def test_unit_quaternion_is_numpys_norm_bit_for_bit():
    """transforms._unit replaces q / np.linalg.norm(q) in the tf lookups (its overhead was 4 % of
    the map thread): the same bits, so poses and maps are those of before."""
    import numpy as np

    from ltmap_cli.io.transforms import _unit

    rng = np.random.default_rng(11)
    for _ in range(20000):
        q = rng.normal(size=4) * rng.uniform(1e-3, 1e3)
        assert _unit(q).tobytes() == (q / np.linalg.norm(q)).tobytes()


def test_a_cached_path_follows_tf_reparenting_a_frame_and_one_edge_lookups_are_the_callers():
    """The per-pair path cache (which edges lead from each frame to their common frame) is dropped
    when tf itself re-parents a frame, and a lookup over a single edge returns the caller's own
    matrix, not the edge's cached one."""
    b = TfBuffer()
    b.add(TfSample(0, "odom", "base_link", (1.0, 0.0, 0.0), yaw_q(0.0)))
    b.add(TfSample(0, "base_link", "cam", (0.5, 0.0, 0.0), yaw_q(0.0)))
    np.testing.assert_allclose(b.lookup("odom", "cam", 0)[:3, 3], [1.5, 0.0, 0.0], atol=1e-12)
    b.add(TfSample(S, "odom", "cam", (0.0, 2.0, 0.0), yaw_q(0.0)))  # the same source re-parents cam
    np.testing.assert_allclose(b.lookup("odom", "cam", S)[:3, 3], [0.0, 2.0, 0.0], atol=1e-12)
    one = b.lookup("odom", "base_link", 0)  # one edge up, then one edge down
    one[0, 3] = 9.0
    assert b.lookup("odom", "base_link", 0)[0, 3] == 1.0
    back = b.lookup("base_link", "odom", 0)
    back[0, 3] = 9.0
    assert b.lookup("base_link", "odom", 0)[0, 3] == -1.0
