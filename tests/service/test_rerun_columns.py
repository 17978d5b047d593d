"""tofd.service.viewer.columns reaches beyond Rerun's documented API (`_ARROW_DATATYPE`, `descriptor_<component>()`):
these tests pin that those names give what Rerun's public conversions give, for every component the logger sends,
so a rerun-sdk upgrade that moves them fails here, not in a viewer."""

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr

from tofd.service.viewer.columns import (
    IMAGE_BUFFER_TYPE,
    component_array,
    component_descriptor,
    component_type,
    image_columns,
    image_format,
)

# (archetype, component, values) of each component the logger sends as a column (tofd.service.viewer.logger)
SENT = [
    (rr.Points3D, "positions", np.array([[0.1, -0.2, 0.5], [0.0, 0.0, 0.7]], np.float32)),
    (rr.Points3D, "colors", np.array([0xFF0000FF, 0x00FF00FF], np.uint32)),
    (rr.Points2D, "positions", np.array([[88.0, 67.0]], np.float32)),
    (rr.Boxes2D, "centers", np.array([[88.5, 67.25]], np.float32)),
    (rr.Boxes2D, "half_sizes", np.array([[4.0, 4.0]], np.float32)),
    (rr.Boxes2D, "labels", ["track 0.93"]),
    (rr.Scalars, "scalars", np.array([3.25])),
    (rr.Transform3D, "translation", np.array([[12.0, 30.0, 0.0]], np.float32)),
]


def public_column(archetype: type, component: str, values: object):
    """The column Rerun's public `Archetype.columns(...)` makes of `values` (one value per row)."""
    (column,) = archetype.columns(**{component: values})
    return column


@pytest.mark.parametrize(("archetype", "component", "values"), SENT,
                         ids=[f"{a.__name__}.{c}" for a, c, _ in SENT])
def test_component_types_and_arrays_equal_rerun_public_conversion(archetype, component, values):
    descriptor, datatype = component_type(archetype, component)
    column = public_column(archetype, component, values)
    assert descriptor == column.component_descriptor() == component_descriptor(archetype, component)
    public = column.as_arrow_array()  # one list of values per row
    assert public.type.value_type == datatype
    ours = component_array(datatype, values if isinstance(values, list) else np.asarray(values))
    assert ours.type == datatype
    assert ours.to_pylist() == public.flatten().to_pylist()


@pytest.mark.parametrize(("archetype", "dtype", "color_model"),
                         [(rr.DepthImage, np.float32, None), (rr.Image, np.uint16, "L"),
                          (rr.SegmentationImage, np.uint8, None)])
def test_image_columns_equal_what_the_archetype_logs(archetype, dtype, color_model):
    """An image's buffer and format columns (built from numpy) are the components the archetype itself makes."""
    pixels = np.arange(6, dtype=dtype).reshape(2, 3)
    kwargs = {} if color_model is None else {"color_model": color_model}
    public = {b.component_descriptor(): b.as_arrow_array() for b in archetype(pixels, **kwargs).as_component_batches()}
    buffers = pa.ListArray.from_arrays(
        [0, pixels.nbytes], pixels.reshape(-1).view(np.uint8), type=IMAGE_BUFFER_TYPE)
    formats = image_format(height=2, width=3, color_model=color_model, dtype=dtype)
    columns = image_columns(archetype, buffers, formats)
    assert [c.component_descriptor() for c in columns] == [component_descriptor(archetype, "buffer"),
                                                           component_descriptor(archetype, "format")]
    sent = {c.component_descriptor(): c.as_arrow_array().flatten() for c in columns}
    for descriptor, array in sent.items():
        assert array.type == public[descriptor].type, descriptor
        assert array.to_pylist() == public[descriptor].to_pylist(), descriptor
