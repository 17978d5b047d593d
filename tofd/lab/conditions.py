"""Sensor conditions the detector is never trained on, for the robustness matrix (tofd.lab.robustness).

Training always renders with the renderer's default SensorModel (`TRAIN_CONDITION`): range noise tied to
amplitude (2 mm at amplitude 20000), flying pixels on 60 % of depth edges, a wall at 1.6 m, face albedo 1.
Each other condition changes one of these, so a failing cell names its cause.
"""

from __future__ import annotations

from tofd.drivers.emulator.render import SensorModel

TRAIN_CONDITION = "train_sensor"

CONDITIONS: dict[str, SensorModel] = {
    TRAIN_CONDITION: SensorModel(),
    "noise_x0.5": SensorModel(range_noise_m=0.001),
    "noise_x2": SensorModel(range_noise_m=0.004),
    # constant noise: the amplitude-tied model's sigma on a frontal face at 0.70 m (2 mm * 20000 / 10200)
    "noise_constant": SensorModel(noise_model="constant", range_noise_m=0.004),
    "no_flying_pixels": SensorModel(flying_pixel_fraction=0.0),
    "wall_0.9m": SensorModel(wall_distance_m=0.9),
    "wall_1.2m": SensorModel(wall_distance_m=1.2),
    "no_wall": SensorModel(wall_distance_m=None),
    "dark_face": SensorModel(face_albedo=0.5),  # half the amplitude: sqrt(2) more noise on the face
    "bright_wall": SensorModel(wall_albedo=1.0),  # wall as bright as the face (Otsu's two classes merge)
}
"""Condition name -> the sensor model rendered under it."""


def parse_conditions(text: str) -> tuple[str, ...]:
    """Comma-separated condition names ("all": every one); ValueError names the unknown ones."""
    names = tuple(CONDITIONS) if text.strip() == "all" else tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in CONDITIONS]
    if unknown or not names:
        bad = ", ".join(unknown) or "(none given)"
        raise ValueError(f"unknown condition(s) {bad} (known: {', '.join(CONDITIONS)})")
    return names
