"""Depth sensor models, one module per sensing principle, each documented with its sources.

- :mod:`builder.sensors.structured_light`: Kinect v1 (preset ``structured_light``);
- :mod:`builder.sensors.active_stereo`: RealSense D4xx (preset ``active_stereo``);
- :mod:`builder.sensors.time_of_flight`: Azure Kinect, Kinect v2 (preset
  ``time_of_flight``);
- :mod:`builder.sensors.edges`: occlusion shadows and mixed pixels, which they share.

They build on the generic pieces of :mod:`builder.depth_noise`, which selects all depth
noise presets by name (:func:`builder.depth_noise.noise_preset`) and runs any of them
(:func:`builder.depth_noise.apply_depth_noise`).
"""

from builder.sensors.active_stereo import ActiveStereoConfig, simulate_active_stereo
from builder.sensors.structured_light import StructuredLightConfig, simulate_structured_light
from builder.sensors.time_of_flight import TimeOfFlightConfig, simulate_time_of_flight

__all__ = [
    "SENSOR_PRESETS",
    "ActiveStereoConfig",
    "StructuredLightConfig",
    "TimeOfFlightConfig",
    "simulate_active_stereo",
    "simulate_structured_light",
    "simulate_time_of_flight",
]

SENSOR_PRESETS: dict[str, StructuredLightConfig | ActiveStereoConfig | TimeOfFlightConfig] = {
    "structured_light": StructuredLightConfig(),
    "active_stereo": ActiveStereoConfig(),
    "time_of_flight": TimeOfFlightConfig(),
}
