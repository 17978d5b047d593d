"""Rerun components as ready Arrow columns for send_columns: the one module that reaches Rerun's internals.

Rerun's Python SDK converts each component batch per call, most of a one-frame send's CPU; these build the
Arrow arrays in each component's own type once, from numpy, and hand them over as they are. The names it uses
beyond Rerun's documented API (each batch class's `_ARROW_DATATYPE`, the archetypes' `descriptor_<component>()`)
are pinned for the rerun-sdk version pyproject.toml allows by tests/service/test_rerun_columns.py.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np
import pyarrow as pa
import rerun as rr
from rerun.components import ImageBufferBatch, ImageFormat, ImageFormatBatch
from rerun.encodings import ColorModelLike

IMAGE_BUFFER_TYPE: pa.DataType = ImageBufferBatch._ARROW_DATATYPE
"""The Arrow type of Rerun's ImageBuffer component (a list of bytes per image)."""


def offsets_of(lengths: Sequence[int] | np.ndarray) -> np.ndarray:
    """(len(lengths) + 1,) int32 offsets: item i spans offsets[i]:offsets[i + 1]."""
    offsets = np.zeros(len(lengths) + 1, np.int32)
    np.cumsum(lengths, out=offsets[1:])
    return offsets


def blobs(flat: np.ndarray, sizes: np.ndarray | Sequence[int], datatype: pa.DataType = IMAGE_BUFFER_TYPE
          ) -> pa.ListArray:
    """Images stored back to back in the 1-D array `flat`, `sizes` elements each, as image buffers (Rerun's
    ImageBuffer arrow type, or another list of bytes: `datatype`) without a copy."""
    return pa.ListArray.from_arrays(pa.array(offsets_of(np.asarray(sizes) * flat.itemsize)),
                                    pa.array(flat.view(np.uint8)), type=datatype)


@dataclass(frozen=True, slots=True)
class ArrowBatch:
    """An arrow array ready in a Rerun component's type, as a component batch (ComponentBatchLike): send_columns
    takes it as it is, without the archetype's per-call conversions (most of a one-frame send's CPU)."""

    descriptor: rr.ComponentDescriptor
    array: pa.Array

    def component_descriptor(self) -> rr.ComponentDescriptor:
        return self.descriptor

    def as_arrow_array(self) -> pa.Array:
        return self.array


def row_columns(*described: tuple[rr.ComponentDescriptor, pa.Array], offsets: np.ndarray | None = None
                ) -> list[rr.ComponentColumn]:
    """Columns from (descriptor, arrow array) pairs: row i holds values offsets[i]:offsets[i + 1] (int32; None:
    one value per row)."""
    if offsets is None:
        offsets = np.arange(len(described[0][1]) + 1, dtype=np.int32)
    return [rr.ComponentColumn(d, ArrowBatch(d, a), offsets=offsets) for d, a in described]


def component_descriptor(archetype: type, component: str) -> rr.ComponentDescriptor:
    """The descriptor of an archetype's component (`component` as in its columns() arguments, e.g. "positions")."""
    descriptor: rr.ComponentDescriptor = getattr(archetype, f"descriptor_{component}")()
    return descriptor


@cache
def component_type(archetype: type, component: str) -> tuple[rr.ComponentDescriptor, pa.DataType]:
    """The descriptor and arrow type of an archetype's component (`component` as in its columns() arguments)."""
    descriptor = component_descriptor(archetype, component)
    batch = getattr(rr.components, str(descriptor.component_type).rsplit(".", 1)[-1] + "Batch")
    datatype: pa.DataType = batch._ARROW_DATATYPE
    return descriptor, datatype


def component_array(datatype: pa.DataType, values: np.ndarray | list) -> pa.Array:
    """Values in a Rerun component's arrow type: fixed-size lists (points, sizes) from (N, k) numbers, else as
    they are (colours, scalars, labels)."""
    if pa.types.is_fixed_size_list(datatype):
        flat = np.ascontiguousarray(values, np.float32).reshape(-1)
        return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=datatype.value_type), type=datatype)
    return pa.array(values, type=datatype)


def image_columns(archetype: type, buffers: pa.ListArray, formats: pa.StructArray,
                  *more: tuple[rr.ComponentDescriptor, pa.Array]) -> list[rr.ComponentColumn]:
    """An image archetype's buffer and format columns (and `more`), one image per row."""
    return row_columns((component_descriptor(archetype, "buffer"), buffers),
                       (component_descriptor(archetype, "format"), formats), *more)


def image_formats(template: pa.StructArray, shapes: Sequence[tuple[int, int]]) -> pa.StructArray:
    """One image format per (height, width) of `shapes`, each otherwise the one-row `template`'s (image_format):
    the formats of a batch of crops of one kind of image."""
    heights, widths = np.asarray(shapes, np.uint32).reshape(-1, 2).T
    at = np.zeros(len(heights), np.intp)
    fields = {field.name: template.field(field.name).take(at) for field in template.type}
    fields["width"], fields["height"] = pa.array(widths, pa.uint32()), pa.array(heights, pa.uint32())
    return pa.StructArray.from_arrays(list(fields.values()), fields=list(template.type))


def image_format(*, height: int, width: int, color_model: ColorModelLike | None, dtype: type) -> pa.StructArray:
    """The one-row image format (Rerun's ImageFormat arrow type) of (height, width) images of `dtype` pixels."""
    return ImageFormatBatch([ImageFormat(width=width, height=height, color_model=color_model,
                                         channel_datatype=rr.ChannelDatatype.from_np_dtype(np.dtype(dtype)))
                             ]).as_arrow_array()
