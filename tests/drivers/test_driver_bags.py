"""ROS 2 driver bags as orbbec_camera, azure_kinect_ros_driver, realsense2_camera and pmd royale publish them
(written with rosbags' writers): the driver is recognised by its topics, z-depth in millimetres or metres, raw or
compressedDepth, becomes radial range through the CameraInfo's lens (rational_polynomial, plumb_bob,
equidistant), and `tofd replay` puts a sphere seen in the distorted corner back on the sphere."""

from __future__ import annotations

import dataclasses
import json
from collections import Counter

import numpy as np
import pytest

from tests.commands.test_cli import one_line_error, tofd
from tofd.drivers.bags.driver_bag import RangeOptions, RosbagSource
from tofd.drivers.bags.driver_layouts import LAYOUTS
from tofd.drivers.bags.join import StreamJoin
from tofd.drivers.bags.opener import open_bag
from tofd.drivers.intrinsics import Intrinsics
from tofd_testing.bag_scenes import FISHEYE_LIKE, K4A_LIKE, RS_LIKE, RS_SCENE, Scene, depth_units, render
from tofd_testing.rosbag_helpers import bag_path, compressed_depth, image, lens_camera_info, typestore, write_bag
from tofd_testing.vendor_bag_helpers import assert_on_sphere, logged_foreground, pinhole_errors, replay_saving_rrd

LAYOUT = {layout.driver: layout for layout in LAYOUTS}
N_FRAMES = 3
STAMP0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333  # 30 fps


def driver_messages(kind: str, driver: str, intrinsics: Intrinsics, scene: Scene, encoding: str,
                    namespace: str | None = None, n_frames: int = N_FRAMES) -> list[tuple[str, object]]:
    """The messages of n_frames of the scene on the driver's topics: depth (16UC1 mm, 32FC1 m, or "compressed":
    16UC1 through compressedDepth), infrared mono16, CameraInfo with the lens, all with the frame's stamp."""
    layout, ts = LAYOUT[driver], typestore(kind)
    base = layout.namespace if namespace is None else namespace
    topics = {role: f"{base}/{rel}" for role, rel in layout.relative_topics.items() if rel is not None}
    z, infrared, _ = render(intrinsics, scene)
    ir16 = np.clip(infrared * 60000, 0, 65535).astype(np.uint16)
    out: list[tuple[str, object]] = []
    for n in range(n_frames):
        stamp = STAMP0_NS + n * PERIOD_NS
        if encoding == "32FC1":
            depth = image(ts, np.where(np.isnan(z), 0, z).astype(np.float32), "32FC1", stamp, frame_id=driver)
        elif encoding == "compressed":
            depth = compressed_depth(ts, depth_units(z, 1e-3), stamp, frame_id=driver)
        else:
            depth = image(ts, depth_units(z, 1e-3), "16UC1", stamp, frame_id=driver)
        out += [(topics["range"], depth), (topics["amplitude"], image(ts, ir16, "mono16", stamp, frame_id=driver)),
                (topics["camera_info"], lens_camera_info(ts, intrinsics, stamp, frame_id=driver))]
    return out


CASES = [  # driver, bag kind, depth encoding, lens, namespace (None: the driver's default)
    ("orbbec_camera", "sqlite3", "16UC1", K4A_LIKE, None),
    ("azure_kinect_ros_driver", "mcap", "32FC1", K4A_LIKE, None),
    ("realsense2_camera", "sqlite3", "compressed", RS_LIKE, None),
    ("royale", "mcap", "32FC1", FISHEYE_LIKE, None),
    ("orbbec_camera", "ros1", "16UC1", K4A_LIKE, "/front_camera"),
]


@pytest.mark.parametrize("driver,kind,encoding,lens,namespace", CASES)
def test_a_driver_bag_is_recognised_and_read_through_its_lens(tmp_path, driver, kind, encoding, lens, namespace):
    scene = RS_SCENE if lens is RS_LIKE else Scene()
    bag = write_bag(bag_path(tmp_path, kind), kind, driver_messages(kind, driver, lens, scene, encoding, namespace))
    with open_bag(bag) as source:
        assert isinstance(source, RosbagSource)
        frames = list(source)
        assert source.options.driver == driver and dict(source.counters) == {}
    assert [f.frame_counter for f in frames] == list(range(N_FRAMES))
    assert [f.timestamp_us for f in frames] == [(STAMP0_NS + n * PERIOD_NS) // 1000 for n in range(N_FRAMES)]
    assert frames[0].intrinsics == lens and frames[0].device.model == driver
    z, infrared, _ = render(lens, scene)
    truth = lens.radial_from_z(z)
    got = frames[-1].range_m
    assert np.array_equal(np.isnan(got), np.isnan(z))  # 0 = no return -> NaN, nothing else
    tolerance = 2e-6 if encoding == "32FC1" else 0.5e-3 / np.nanmin(lens.unit_rays()[..., 2])  # float32 / 1 mm steps
    assert np.nanmax(np.abs(got - truth)) <= tolerance
    assert np.array_equal(frames[-1].amplitude, np.clip(infrared * 60000, 0, 65535).astype(np.uint16))


@pytest.mark.slow
def test_replay_of_an_orbbec_driver_bag_puts_the_foreground_on_the_sphere(tmp_path):
    """The done-when: a ROS 2 bag with rational_polynomial (K4A-like) distortion, sphere in the distorted corner."""
    bag = write_bag(bag_path(tmp_path, "sqlite3", "femto"), "sqlite3",
                    driver_messages("sqlite3", "orbbec_camera", K4A_LIKE, Scene(), "16UC1"))
    proc = replay_saving_rrd(bag, tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert f"imported {N_FRAMES} frames of 320x288" in proc.stderr
    _, _, sphere = render(K4A_LIKE, Scene())
    foreground = logged_foreground(tmp_path / "out" / "femto.rrd")
    assert len(foreground) == N_FRAMES
    for points in foreground:
        assert_on_sphere(points, Scene(), int(sphere.sum()))
    assert pinhole_errors(K4A_LIKE, Scene()) > 10e-3  # ignoring the lens would put it centimetres off


def test_image_transport_topics_stand_for_their_image(tmp_path):
    """A driver's depth recorded through image_transport's compressedDepth plugin (`<depth image>/compressedDepth`,
    the raw topic absent): the driver and its other topics are found with --range-topic naming it, or with no
    topic option at all."""
    messages = driver_messages("mcap", "orbbec_camera", K4A_LIKE, Scene(), "compressed", namespace="/cam1")
    messages = [(topic + "/compressedDepth" if topic.endswith("/depth/image_raw") else topic, msg)
                for topic, msg in messages]
    bag = write_bag(bag_path(tmp_path, "mcap"), "mcap", messages)
    z, _, _ = render(K4A_LIKE, Scene())
    for args in (["--range-topic", "/cam1/depth/image_raw/compressedDepth"], []):
        proc = tofd("info", str(bag), "--json", *args)
        assert proc.returncode == 0, proc.stderr
        assert json.loads(proc.stdout)["frames"] == N_FRAMES
    with RosbagSource(bag, RangeOptions(range_topic="/cam1/depth/image_raw/compressedDepth")) as source:
        frames = list(source)
        assert source.options.driver == "orbbec_camera"
        assert source.options.topics == {"range": "/cam1/depth/image_raw/compressedDepth",
                                         "amplitude": "/cam1/ir/image_raw", "camera_info": "/cam1/depth/camera_info"}
    got = frames[-1].range_m
    assert len(frames) == N_FRAMES and np.array_equal(np.isnan(got), np.isnan(z))
    assert np.nanmax(np.abs(got - K4A_LIKE.radial_from_z(z))) <= 0.5e-3 / np.nanmin(K4A_LIKE.unit_rays()[..., 2])


def test_options_override_what_the_driver_layout_says(tmp_path):
    """--depth radial takes the depth image as it is; with every topic named no driver layout is needed."""
    bag = write_bag(bag_path(tmp_path, "mcap"), "mcap", driver_messages("mcap", "royale", FISHEYE_LIKE, Scene(),
                                                                          "32FC1", namespace="/tof"))
    topics = {"range_topic": "/tof/depth_image", "amplitude_topic": "/tof/gray_image",
              "camera_info_topic": "/tof/camera_info"}
    with RosbagSource(bag, RangeOptions(**topics, depth="radial")) as source:
        radial_as_given = next(iter(source))
        assert source.options.driver == ""
    z, _, _ = render(FISHEYE_LIKE, Scene())
    np.testing.assert_allclose(radial_as_given.range_m, z.astype(np.float32), equal_nan=True)


def test_arena_camera_bag_says_what_is_missing(tmp_path):
    ts = typestore("sqlite3")
    z, _, _ = render(FISHEYE_LIKE, Scene())
    bag = write_bag(bag_path(tmp_path, "sqlite3"), "sqlite3",
                    [("/arena_camera_node/images", image(ts, depth_units(z, 1e-3), "16UC1", STAMP0_NS))])
    one_line_error(tofd("import", str(bag), str(tmp_path / "out.mcap")), 2, "arena_camera driver's bag has no "
                   "amplitude topic", "--amplitude-topic", "/arena_camera_node/images (sensor_msgs/msg/Image)")


def test_a_bag_of_no_known_driver_lists_its_topics(tmp_path):
    ts = typestore("mcap")
    z, _, _ = render(FISHEYE_LIKE, Scene())
    bag = write_bag(bag_path(tmp_path, "mcap"), "mcap",
                    [("/lidar/depth", image(ts, depth_units(z, 1e-3), "16UC1", STAMP0_NS))])
    one_line_error(tofd("import", str(bag), str(tmp_path / "out.mcap")), 2, "no known camera driver's topics",
                   "orbbec_camera", "/lidar/depth (sensor_msgs/msg/Image)")


def test_an_unsupported_lens_model_is_refused_naming_it(tmp_path):
    messages = driver_messages("sqlite3", "orbbec_camera", K4A_LIKE, Scene(), "16UC1", n_frames=1)
    info = messages[2][1]
    messages[2] = (messages[2][0], dataclasses.replace(info, distortion_model="fov", d=np.array([0.3])))
    bag = write_bag(bag_path(tmp_path, "sqlite3"), "sqlite3", messages)
    one_line_error(tofd("import", str(bag), str(tmp_path / "out.mcap")), 2, f"{bag}: /camera/depth/camera_info",
                   "distortion model 'fov'", "rational_polynomial")


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_a_driver_bag_cut_short_imports_the_frames_before_the_cut(tmp_path, kind):
    """A bag cut short loses its index (ROS 1), summary (MCAP) or last pages (sqlite3): the messages before the cut
    are read record by record, the rest is ledgered as one rejected frame."""
    n_frames = 8
    messages = driver_messages(kind, "orbbec_camera", K4A_LIKE, Scene(), "16UC1", n_frames=n_frames)
    bag = write_bag(bag_path(tmp_path, kind, "long"), kind, messages, chunk_bytes=200_000)
    storage = bag if kind == "ros1" else next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
    data = storage.read_bytes()
    storage.write_bytes(data[:len(data) * 2 // 3])
    proc = tofd("import", str(bag), str(tmp_path / "cut.mcap"))
    assert proc.returncode == 0 and "damaged, the rest unread" in proc.stderr, proc.stderr
    written = int(proc.stderr.split("wrote ")[1].split(": ")[1].split(" frames")[0])
    assert 1 <= written < n_frames
    with RosbagSource(bag) as source:
        frames = list(source)
        rejected = source.take_rejected()
    assert [f.frame_counter for f in frames] == list(range(written))
    assert [r.frame_counter for r in rejected] == [written] and rejected[0].reason.startswith(f"damaged: {bag}")
    z, _, _ = render(K4A_LIKE, Scene())
    assert np.nanmax(np.abs(frames[-1].range_m - K4A_LIKE.radial_from_z(z))) <= 1e-3  # intact frames, not garbage


def test_a_garbled_frame_in_the_middle_is_ledgered_and_the_rest_read(tmp_path):
    """A compressedDepth image whose PNG is garbled, and an IR image shorter than its rows: the first frame is
    ledgered as damaged by its counter, the second's range image is left unpaired; the others are read."""
    messages = driver_messages("sqlite3", "realsense2_camera", RS_LIKE, RS_SCENE, "compressed", n_frames=4)
    depth_topic, depth = messages[3]  # frame 1's depth
    data = np.array(depth.data)
    data[40:80] = 0xEE
    messages[3] = (depth_topic, dataclasses.replace(depth, data=data))
    ir_topic, ir = messages[7]  # frame 2's IR
    messages[7] = (ir_topic, dataclasses.replace(ir, data=np.array(ir.data)[:-100]))
    bag = write_bag(bag_path(tmp_path, "sqlite3"), "sqlite3", messages)
    with RosbagSource(bag) as source:
        frames = list(source)
        rejected = source.take_rejected()
        counters = dict(source.counters)
    assert [f.frame_counter for f in frames] == [0, 3]
    assert [r.frame_counter for r in rejected] == [1, 2]
    assert rejected[0].reason.startswith(f"damaged: {bag}") and "do not decode" in rejected[0].reason
    assert "infra1/image_rect_raw" in rejected[1].reason and "expected 192 rows" in rejected[1].reason
    assert counters == {"damaged": 2}
    proc = tofd("import", str(bag), str(tmp_path / "out.mcap"))
    assert proc.returncode == 0 and "2 frames of 256x192; skipped 2 frames lost or damaged" in proc.stderr, proc.stderr


def test_the_stream_join_pairs_by_key_and_counts_what_it_gives_up():
    """Parts pair by key in any order; a repeated part, a key pushed out past the limit and the keys left at the
    end are counted as unpaired by role."""
    counters: Counter[str] = Counter()
    join: StreamJoin[int, str] = StreamJoin(("range", "amplitude"), counters, limit=2)
    assert join.add(1, "range", "r1") is None
    assert join.add(1, "amplitude", "a1") == {"range": "r1", "amplitude": "a1"}
    assert join.add(2, "amplitude", "a2") is None
    assert join.add(2, "amplitude", "a2'") is None  # the first a2 is given up
    assert join.add(3, "range", "r3") is None and join.add(4, "range", "r4") is None  # key 2 pushed out
    assert join.add(3, "amplitude", "a3") == {"range": "r3", "amplitude": "a3"}
    assert counters == {"unpaired_amplitude": 2}
    join.finish()  # key 4 never completed
    assert counters == {"unpaired_amplitude": 2, "unpaired_range": 1}
