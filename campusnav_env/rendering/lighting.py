"""
The light of one moment: sky colours, sun direction and colour, ambient and ground light, lit windows, and the haze
that fades distant colours towards the horizon.

:func:`lighting_at` gives the light of an hour (``None`` = fixed noon), with random cloud cover and exposure drawn from
an rng; :func:`fog_amount` the share of haze at a distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FOG_DISTANCE", "FOG_START", "Lighting", "fog_amount", "lighting_at"]

FOG_START = 40.0  # haze begins beyond this distance, so that nearby colours stay true (m)
FOG_DISTANCE = 900.0  # e-folding distance of the haze beyond FOG_START (m)


@dataclass(frozen=True)
class Lighting:
    """Colours and light multipliers of one moment (all float32, colours on the 0..255 scale)."""

    sky_top: np.ndarray
    sky_horizon: np.ndarray
    haze: np.ndarray
    sun_dir: np.ndarray  # horizontal unit vector towards the sun (east, north)
    sun: np.ndarray  # direct light on a wall facing the sun, per channel
    ambient: np.ndarray  # light on a wall in shade, per channel
    ground: np.ndarray  # light on the ground, per channel
    lit_windows: float  # share of windows lit from inside
    window_sky: float  # how much the sky reflects in the glass


def _smoothstep(a: float, b: float, x: float) -> float:
    t = min(1.0, max(0.0, (x - a) / (b - a)))
    return t * t * (3.0 - 2.0 * t)


def _mix(a: tuple[float, ...] | np.ndarray, b: tuple[float, ...] | np.ndarray, t: float) -> np.ndarray:
    return np.asarray(a, dtype=np.float32) * (1.0 - t) + np.asarray(b, dtype=np.float32) * t


def lighting_at(hour: float | None, rng: np.random.Generator | None) -> Lighting:
    """Sun position and colours for ``hour`` (``None`` = fixed noon), with cloud and exposure jitter from ``rng``."""
    cloud, exposure = 0.15, 1.0
    if hour is None:
        hour = 12.0
    elif rng is not None:
        cloud = float(rng.uniform(0.0, 0.75))
        exposure = float(rng.uniform(0.9, 1.1))
    elevation = 62.0 * math.sin(math.pi * (hour - 6.0) / 12.0)
    azimuth = math.radians((90.0 + (hour - 6.0) * 15.0) % 360.0)
    day = _smoothstep(-8.0, 6.0, elevation)
    golden = 1.0 - _smoothstep(2.0, 22.0, elevation)
    top = _mix(_mix((8, 12, 30), (72, 92, 150), day), _mix((62, 118, 200), (88, 104, 160), golden), day)
    horizon = _mix(_mix((26, 32, 56), (236, 160, 104), day), _mix((184, 208, 232), (244, 176, 120), golden), day)
    grey = np.float32(0.72 * day + 0.12) * np.float32(230)
    top = _mix(top, (grey, grey, grey + 6), 0.8 * cloud)
    horizon = _mix(horizon, (grey + 8, grey + 8, grey + 10), 0.7 * cloud)
    sun_colour = _mix((1.0, 0.98, 0.94), (1.0, 0.72, 0.48), golden)
    direct = day * min(1.0, max(0.0, math.sin(math.radians(elevation)) * 2.5)) * (1.0 - 0.85 * cloud)
    ambient = _mix((0.16, 0.18, 0.28), (0.6, 0.62, 0.66), day) * np.float32(1.0 + 0.15 * cloud * day)
    sun = sun_colour * np.float32(0.5 * direct * math.cos(math.radians(max(elevation, 0.0))))
    ground = ambient * np.float32(0.85) + sun_colour * np.float32(
        0.45 * direct * max(0.2, math.sin(math.radians(elevation)))
    )
    scale = np.float32(exposure)
    return Lighting(
        sky_top=top * scale,
        sky_horizon=horizon * scale,
        haze=horizon * scale,
        sun_dir=np.array([math.sin(azimuth), math.cos(azimuth)]),
        sun=sun * scale,
        ambient=ambient * scale,
        ground=ground * scale,
        lit_windows=0.4 * (1.0 - day),
        window_sky=0.25 * day,
    )


def fog_amount(z: np.ndarray) -> np.ndarray:
    """Share of haze (0..1) in the colour of what lies ``z`` m ahead: none up to :data:`FOG_START`."""
    beyond = np.maximum(np.asarray(z, dtype=np.float32) - np.float32(FOG_START), np.float32(0.0))
    return (1.0 - np.exp(-beyond / np.float32(FOG_DISTANCE))).astype(np.float32)
