"""The entity tree tofd logs to Rerun and the blueprint that lays its views out."""

from __future__ import annotations

import rerun.blueprint as rrb

from tofd.algorithm.names import VIEWED_MAPS, map_parts

CAMERA = "/world/camera"  # Pinhole (intrinsics); x right, y down, z forward, metres
IMAGE = f"{CAMERA}/image"  # the camera's image plane: 2-D views of range, amplitude, mask line up with 3-D
RANGE = f"{IMAGE}/depth"  # DepthImage: z-depth (planar, along the optical axis), metres: projects correctly in 3-D
AMPLITUDE = f"{IMAGE}/amplitude"  # EncodedImage: amplitude for viewing, 8-bit JPEG, AMPLITUDE_SCALE units per level
AMPLITUDE_SCALE = "/amplitude_scale"  # Scalars: sensor units per level of AMPLITUDE (its level 255: a robust top)
MASK = f"{IMAGE}/mask"  # SegmentationImage: 1 foreground, 0 background, over the foreground's box, translated to it
NOSE_2D = f"{IMAGE}/nose"  # Points2D: detected nose tip, pixels
FOREGROUND = "/world/foreground"  # Points3D: foreground points, metres, in the colours of their NFFT eps0 view pixels
NOSE_3D = "/world/nose"  # Points3D: detected nose tip, metres
TRACK_2D = f"{IMAGE}/nose_track"  # Boxes2D: the confirmed nose track, pixels, labelled with its confidence
TRACK_3D = "/world/nose_track"  # Points3D: the confirmed nose track, metres
TRACK_CONFIDENCE = "/track/confidence"  # Scalars: the nose track's confidence (0-1), every frame
FEATURES_ORIGIN = "/features"  # the feature views' space: image pixels, like IMAGE's
FEATURES = {name: f"{FEATURES_ORIGIN}/{family.method}/{eps}"
            for name in VIEWED_MAPS for family, eps in [map_parts(name)]}
"""Feature map name -> entity (range_fft_eps0 -> /features/fft/eps0; the viewed maps are the range's): colour-mapped
scalar images of the foreground's bounding box, each translated to where that box lies in the image."""
TIMINGS = "/timings"  # Scalars: milliseconds, one per stage of stats.TIMED_STAGES, in its order (NaN: not timed)
EVENTS = "/events"  # TextLog: device gaps and reconnects


COLUMN_SHARES = (1, 2, 2)
"""Widths of the layout's columns, left to right: camera images, feature maps, 3-D scene and time series."""


def build_blueprint(image_shape: tuple[int, int]) -> rrb.Blueprint:
    """Camera images (left), feature maps (middle), 3-D scene, stage timings, track confidence and device events
    (right); `image_shape` (rows, columns): the 2-D views show the whole image, not just a crop."""

    whole_image = rrb.VisualBounds2D(x_range=[0, image_shape[1]], y_range=[0, image_shape[0]])

    def image_view(name: str, entity: str) -> rrb.Spatial2DView:
        return rrb.Spatial2DView(name=name, origin=IMAGE, contents=[entity, NOSE_2D, TRACK_2D],
                                 visual_bounds=whole_image)

    def feature_view(name: str) -> rrb.Spatial2DView:
        family, eps = map_parts(name)
        return rrb.Spatial2DView(name=f"{family.method.upper()} {eps}", origin=FEATURES_ORIGIN,
                                 contents=[FEATURES[name]], visual_bounds=whole_image)

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(image_view("depth z [m]", RANGE), image_view("amplitude", AMPLITUDE),
                         image_view("foreground mask", MASK)),
            rrb.Grid(*(feature_view(name) for name in FEATURES), grid_columns=2),
            rrb.Vertical(
                rrb.Spatial3DView(name="3-D (camera frame)", origin="/world",
                                  contents=["+ /world/**", f"- {IMAGE}/**"]),
                rrb.TimeSeriesView(name="stage timings [ms]", origin=TIMINGS),
                rrb.TimeSeriesView(name="nose track confidence", origin=TRACK_CONFIDENCE),
                rrb.TextLogView(name="events", origin=EVENTS),
                row_shares=[3, 2, 1, 1]),
            column_shares=list(COLUMN_SHARES)),
        collapse_panels=True)
