"""Reading a tofd .rrd back with Rerun's own reader (rerun.chunk.RrdReader), shared by the sink and daemon tests."""

import warnings

import matplotlib
import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.encoding import code_unit_m, unpng
from tofd.service.viewer.pixels import cloud_pixels

PER_FRAME = [bp.RANGE, bp.AMPLITUDE, bp.MASK, bp.FOREGROUND, *bp.FEATURES.values(), bp.TIMINGS]


def has_footer(path) -> bool:
    """Whether an .rrd file ends with Rerun's footer (chunk index); the reader warns when it has none."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        RrdReader(path)
    return not any("no footer" in str(w.message) for w in caught)


def read_entities(path):
    """entity path -> (static chunks, pyarrow table of the temporal rows sorted by frame)."""
    chunks = list(RrdReader(path).stream().to_chunks())
    tables = {}
    for entity in {c.entity_path for c in chunks}:
        batches = [c.to_record_batch() for c in chunks if c.entity_path == entity and not c.is_static]
        static = [c for c in chunks if c.entity_path == entity and c.is_static]
        # rows of other archetypes (a Clear between points) have other columns: missing ones are null
        table = (pa.concat_tables([pa.Table.from_batches([b]) for b in batches], promote_options="default")
                 .sort_by("frame") if batches else None)
        tables[entity] = (static, table)
    return tables


def foreground_clouds(path):
    """The .rrd's foreground clouds in frame order: one (N, 3) float64 array of camera-frame points (m) a frame."""
    _, table = read_entities(str(path))[bp.FOREGROUND]
    return [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in table.column("Points3D:positions").to_pylist()]


def image_at(table, archetype, row):
    fmt = table.column(f"{archetype}:format")[row].as_py()[0]
    blob = table.column(f"{archetype}:buffer")[row].values[0].values
    dtype = rr.ChannelDatatype(fmt["channel_datatype"]).to_np_dtype()
    return np.frombuffer(blob.to_numpy(zero_copy_only=False).tobytes(), dtype=dtype).reshape(fmt["height"],
                                                                                              fmt["width"])


def blob_at(table, archetype, row):
    """The bytes of an encoded image's blob at `row`."""
    return table.column(f"{archetype}:blob")[row].values[0].values.to_numpy(zero_copy_only=False).tobytes()


def static_value(tables, entity, column):
    """The one value of a component logged statically on `entity` (e.g. "EncodedDepthImage:meter")."""
    for chunk in tables[entity][0]:
        batch = chunk.to_record_batch()
        if column in batch.schema.names:
            return batch.column(column)[0].as_py()[0]
    raise KeyError(f"{column} is not logged statically on {entity}")


def depth_at(tables, row):
    """The z-depth image at `row` as the viewer shows it, in metres (float64), and the stored pixels: a 16-bit PNG
    in the source's unit (EncodedDepthImage, its static meter) or float32 metres (DepthImage)."""
    table = tables[bp.RANGE][1]
    if "EncodedDepthImage:blob" in table.column_names:
        assert static_value(tables, bp.RANGE, "EncodedDepthImage:media_type") == "image/png"
        stored = unpng(blob_at(table, "EncodedDepthImage", row))
        return stored / float(static_value(tables, bp.RANGE, "EncodedDepthImage:meter")), stored
    stored = image_at(table, "DepthImage", row)
    return stored.astype(np.float64) / float(static_value(tables, bp.RANGE, "DepthImage:meter")), stored


def amplitude_at(tables, row):
    """The (H, W) uint8 amplitude image at `row` (a JPEG) and its scale, sensor units per level (the
    AMPLITUDE_SCALE series at the same frame)."""
    table = tables[bp.AMPLITUDE][1]
    assert static_value(tables, bp.AMPLITUDE, "EncodedImage:media_type") == "image/jpeg"
    image = unpng(blob_at(table, "EncodedImage", row))
    scales = tables[bp.AMPLITUDE_SCALE][1]
    at = scales.column("frame").to_pylist().index(table.column("frame")[row].as_py())
    return image, scales.column("Scalars:scalars")[at].as_py()[0]


def check_amplitude(image, scale, amplitude):
    """The 8-bit `image` shows `amplitude` (sensor units) at `scale` units per level: the positive amplitudes'
    99.5th percentile is level 255 (of a subsample: within 5 %), and each pixel is its amplitude's level (rounded,
    saturating at 255) within JPEG's error (rms 2 levels, mean half a level)."""
    assert image.dtype == np.uint8 and image.shape == amplitude.shape
    positive = amplitude[amplitude > 0]
    assert scale == pytest.approx(np.percentile(positive, 99.5) / 255, rel=0.05)
    error = image.astype(np.float64) - np.minimum(np.rint(np.nan_to_num(amplitude) / scale), 255)
    assert np.sqrt(np.mean(error**2)) <= 2.0 and abs(error.mean()) <= 0.5


def placed_at(table, row, crop, shape):
    """`crop` (h, w) at the entity's translation at `row` in an (H, W) image of zeros (float64)."""
    x, y, z = table.column("Transform3D:translation")[row].as_py()[0]
    assert z == 0 and x == int(x) and y == int(y), (x, y, z)
    full = np.zeros(shape, np.float64)
    full[int(y): int(y) + crop.shape[0], int(x): int(x) + crop.shape[1]] = crop
    return full


def mask_at(table, row, shape):
    """The (H, W) bool mask at `row` as the viewer draws it: its crop (a SegmentationImage) placed at its
    translation."""
    crop = image_at(table, "SegmentationImage", row)
    assert crop.dtype == np.uint8 and set(np.unique(crop)) <= {0, 1}
    return placed_at(table, row, crop, shape) > 0


def feature_crop_at(table, row):
    """A feature entity's crop at `row`: its 8-bit levels (a depth image) and its meter (levels per unit)."""
    levels = image_at(table, "DepthImage", row)
    return levels, table.column("DepthImage:meter")[row].as_py()[0]


def feature_map_at(table, row, shape):
    """A feature entity's map at `row` as the viewer draws it, in its own unit (float64): its crop's levels over
    its meter, placed at its translation in an (H, W) image of zeros."""
    levels, meter = feature_crop_at(table, row)
    assert levels.dtype == np.uint8
    return placed_at(table, row, levels / meter, shape)


def check_feature_map(shown, values):
    """`shown` (feature_map_at) is the map `values` (NaN: 0) in 8-bit levels of its largest value: within half a
    level everywhere, its largest value exact (to float32 round-off)."""
    want = np.nan_to_num(values, nan=0.0).astype(np.float64)
    top = want.max()
    np.testing.assert_allclose(shown, want, atol=0.5 * top / 255 * (1 + 1e-5) + 1e-30)
    assert shown.max() == pytest.approx(top, rel=1e-5)


def check_rrd(path, counters, results_by_counter=None):
    """Every entity logged per frame has one row for each delivered frame counter (None: the same rows as the
    range image); statics are there."""
    tables = read_entities(str(path))
    if counters is None:
        counters = tables[bp.RANGE][1].column("frame").to_pylist()
    for entity in PER_FRAME:
        assert entity in tables, f"{entity} missing from {path}"
        rows = tables[entity][1].column("frame").to_pylist()
        assert rows == counters, entity
    assert tables[bp.CAMERA][0], "the Pinhole is logged statically"
    for entity, (_, table) in tables.items():  # Rerun's viewer plays encoded images as a video: one size
        archetype = next((a for a in ("EncodedImage", "EncodedDepthImage") if table is not None
                          and f"{a}:blob" in table.column_names), None)
        if archetype is not None:
            sizes = {unpng(blob_at(table, archetype, row)).shape for row in range(table.num_rows)}
            assert len(sizes) == 1, (entity, sizes)
    device_time = tables[bp.RANGE][1].column("device_time").cast(pa.int64()).to_numpy()
    assert np.all(np.diff(device_time) > 0)
    if results_by_counter:
        c = counters[-1]
        last = len(counters) - 1
        depth_m, stored = depth_at(tables, last)
        frame = results_by_counter[c].frame
        ray_z = frame.intrinsics.unit_rays().astype(np.float32)[..., 2]
        z_m = np.nan_to_num(frame.range_m, nan=0.0) * ray_z  # z-depth of the range
        if stored.dtype == np.float32:
            np.testing.assert_array_equal(stored, z_m)
        else:  # uint16 in the source's unit: whole units of it, or the nearest SR3000 code
            assert stored.dtype == np.uint16
            if frame.sensor is not None:
                unit = frame.sensor.depth_unit_m
                np.testing.assert_array_equal(stored, np.rint(z_m / unit))
                np.testing.assert_allclose(depth_m, z_m, atol=unit * 0.05)
            else:
                unit = code_unit_m(frame)
                np.testing.assert_allclose(depth_m, z_m, rtol=0, atol=unit * 0.52)  # and float32 round-off
        check_amplitude(*amplitude_at(tables, last), results_by_counter[c].frame.amplitude)
        mask = results_by_counter[c].mask
        np.testing.assert_array_equal(mask_at(tables[bp.MASK][1], last, mask.shape), mask)  # the crop, in place
        assert image_at(tables[bp.MASK][1], "SegmentationImage", last).size < 0.5 * mask.size
        cloud = tables[bp.FOREGROUND][1].column("Points3D:positions")[len(counters) - 1]
        at = cloud_pixels(results_by_counter[c].mask)
        assert len(cloud) == len(at)
        # coloured as the NFFT eps0 view shows their pixels: its 8-bit level on viridis, the largest value yellow
        colours = tables[bp.FOREGROUND][1].column("Points3D:colors")[len(counters) - 1].values.to_numpy()
        eps0 = tables[bp.FEATURES["range_nfft_eps0"]][1]
        levels = np.rint(feature_map_at(eps0, last, frame.range_m.shape) * feature_crop_at(eps0, last)[1])
        assert len(colours) == len(at)
        rgb = np.stack([colours >> 24, colours >> 16 & 0xFF, colours >> 8 & 0xFF], axis=1)
        viridis = (matplotlib.colormaps["viridis"](levels.reshape(-1)[at] / 255)[:, :3] * 255).astype(int)
        np.testing.assert_array_equal(rgb, viridis)
        top = np.nanargmax(results_by_counter[c].features["range_nfft_eps0"].reshape(-1)[at])
        assert tuple(rgb[top]) == (253, 231, 36)  # viridis at 1
        for name, entity in bp.FEATURES.items():  # each map, cropped to the foreground, is the whole map in place
            shown = feature_map_at(tables[entity][1], last, frame.range_m.shape)
            check_feature_map(shown, results_by_counter[c].features[name])
            assert feature_crop_at(tables[entity][1], last)[0].size < 0.5 * shown.size
    return tables


def live_recording(path) -> str:
    """The one segment a short live run with the .rrd `path` wrote (a live file is cut into numbered segments by
    default, [rerun] rotate_mb: STEM.00000.rrd, ...)."""
    segments = sorted(path.parent.glob(f"{path.stem}.*.rrd"))
    assert [s.name for s in segments] == [f"{path.stem}.00000.rrd"] and not path.exists(), segments
    return str(segments[0])
