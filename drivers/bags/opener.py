"""Opens any ROS bag tofd takes as the frame source its content calls for: a RealSense SDK recording, an Orbbec
SDK v2 recording, or a camera driver's bag (bags.driver_bag, topics from bags.driver_layouts or the options).

The vendor recordings are recognised by their topics (RealSense: /file_version and /device_<d>/sensor_<s>/Depth_*;
Orbbec: /cam/sensor_3/frameType_*), so a renamed file is read all the same.
"""

from __future__ import annotations

from pathlib import Path

from tofd.drivers.bags.driver_bag import RangeOptions, RosbagSource
from tofd.drivers.bags.orbbec import OrbbecSource, is_orbbec
from tofd.drivers.bags.realsense import RealSenseSource, is_realsense
from tofd.drivers.bags.scan import BagError, BagReader
from tofd.drivers.bags.source import BagSource


def bag_kind(bag: BagReader) -> str:
    """"realsense", "orbbec" or "driver" (a camera driver's bag) by the open bag's topics."""
    return "realsense" if is_realsense(bag.topics) else "orbbec" if is_orbbec(bag.topics) else "driver"


def open_bag(path: str | Path, options: RangeOptions | None = None, bag: BagReader | None = None) -> BagSource:
    """The frame source of the bag at `path` (`bag`: the bag already open, handed on to the source; BagError if
    it cannot be read). Topic and range options apply to driver bags only: a vendor SDK recording says itself
    where its frames are and in what unit (BagError if options are given for one)."""
    options = options or RangeOptions()
    bag = bag or BagReader(path)
    try:
        kind = bag_kind(bag)
        if kind == "driver":
            return RosbagSource(path, options, bag)
        if options != RangeOptions(mod_freq_mhz=options.mod_freq_mhz):
            raise BagError(f"{path}: a {'RealSense' if kind == 'realsense' else 'Orbbec'} SDK recording says where "
                           "its frames are and their units; the topic and range options are for camera drivers' bags")
        return RealSenseSource(path, bag) if kind == "realsense" else OrbbecSource(path, bag)
    except BaseException:
        bag.close()
        raise
