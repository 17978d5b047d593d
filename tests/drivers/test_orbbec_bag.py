"""Orbbec SDK v2 recordings written by the SDK's own RecordDevice (ROS 1, LZ4 or plain chunks, the SDK's extended
Image and custom messages): recognised by content, depth in the unit the file gives through the stream profile's
Brown-Conrady K6 lens lands on the sphere, device identity and numbers from the file."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from tests.commands.test_cli import one_line_error, tofd
from tofd.drivers.bags.opener import open_bag
from tofd.drivers.bags.orbbec import PROPERTY_DEPTH_UNIT_MM, OrbbecSource
from tofd.drivers.opener import identify
from tofd.drivers.recording.replay import iter_frames
from tofd_testing.bag_scenes import K4A_LIKE, Scene, depth_units, render, sphere_errors
from tofd_testing.orbbec_bag_helpers import write_orbbec_bag, write_seed_bag

N_FRAMES = 3
K = (K4A_LIKE.fx, K4A_LIKE.fy, K4A_LIKE.cx, K4A_LIKE.cy)
k1, k2, p1, p2, k3, k4, k5, k6 = K4A_LIKE.distortion
SDK_ORDER = (k1, k2, k3, k4, k5, k6, p1, p2)


def femto_bag(path, **kwargs):
    z, infrared, _ = render(K4A_LIKE, Scene())
    depth = depth_units(z, 1e-3)
    ir = np.clip(infrared * 60000, 0, 65535).astype(np.uint16)
    return write_orbbec_bag(path, [depth] * N_FRAMES, [ir] * N_FRAMES, K, SDK_ORDER, **kwargs)


@pytest.mark.parametrize("compressed", [True, False])
def test_an_orbbec_recording_reads_with_its_lens_units_numbers_and_device(tmp_path, compressed):
    bag = femto_bag(tmp_path / "femto.bag", compressed=compressed)
    assert identify(bag).name == "orbbec"
    with open_bag(bag) as source:
        assert isinstance(source, OrbbecSource)
        frames = list(source)
        numbers = [f.frame_counter for f in frames]
        assert numbers in ([6, 7, 8, 9], [7, 8, 9])  # the SDK's recorder may lose the lead-in's depth image
        assert source.settings["depth_units_mm"] == 1.0
        assert dict(source.counters) == ({} if 6 in numbers else {"unpaired_amplitude": 1})
    frames = frames[-N_FRAMES:]
    assert [f.timestamp_us for f in frames] == [5_000_000 + round(n * 1e6 / 30) for n in range(N_FRAMES)]
    device = frames[0].device
    assert (device.backend, device.model, device.serial, device.firmware) == ("orbbec", "Femto Bolt", "CL8F12300AB",
                                                                             "1.0.9")
    lens = frames[0].intrinsics
    assert lens.distortion_model == "rational_polynomial"
    np.testing.assert_allclose(lens.distortion, K4A_LIKE.distortion, rtol=1e-6, atol=1e-9)  # float32 in the file
    z, _, sphere = render(K4A_LIKE, Scene())
    points = lens.backproject(frames[0].range_m)[sphere]
    errors = sphere_errors(points, Scene())
    assert np.median(errors) <= 1e-3 and np.percentile(errors, 90) <= 2e-3
    assert np.array_equal(np.isnan(frames[0].range_m), np.isnan(z))


def test_the_depth_unit_property_scales_the_depth(tmp_path):
    """The SDK's recorder writes the depth unit (property 176) for Gemini 330 cameras only, whose stereo depth
    its playback device cannot stand in for here: this bag is laid out as the SDK reads it, not re-recorded."""
    z, infrared, _ = render(K4A_LIKE, Scene())
    depth = depth_units(z, 0.5e-3)
    bag = write_seed_bag(tmp_path / "half_mm.bag", [depth], [np.zeros_like(depth)], K, SDK_ORDER,
                         properties={PROPERTY_DEPTH_UNIT_MM: struct.pack("<f", 0.5)})
    with open_bag(bag) as source:
        frames = list(source)
        assert source.settings["depth_units_mm"] == 0.5
    z_read = frames[0].intrinsics.backproject(frames[0].range_m)[..., 2]
    np.testing.assert_allclose(z_read, z, atol=0.3e-3)  # half a unit of 0.5 mm, and float32


def test_an_orbbec_recording_imports_and_keeps_the_lens(tmp_path):
    bag = femto_bag(tmp_path / "femto.bag")
    proc = tofd("import", str(bag), str(tmp_path / "femto.mcap"))
    assert proc.returncode == 0 and "frames of 320x288" in proc.stderr, proc.stderr
    frames = list(iter_frames(tmp_path / "femto.mcap"))
    assert [f.frame_counter for f in frames][-N_FRAMES:] == [7, 8, 9]
    assert frames[0].intrinsics.distortion_model == "rational_polynomial"


def test_a_recording_stopped_without_its_stream_profiles_is_one_line_exit_2(tmp_path):
    """The SDK writes the intrinsics when recording stops: a recording cut short has none to read (the SDK's
    writer always finishes its files, so this one is laid out by hand)."""
    z, infrared, _ = render(K4A_LIKE, Scene())
    bag = write_seed_bag(tmp_path / "cut.bag", [depth_units(z, 1e-3)], [np.zeros_like(z, np.uint16)], K, SDK_ORDER,
                         profiles=False)
    one_line_error(tofd("import", str(bag), str(tmp_path / "out.mcap")), 2, str(bag),
                   "no /cam/streamProfileType_3", "written when recording stops")
