"""Physical ranges of every number a message carries: the one place that defines them.

Each quantity is an ``Annotated`` float or int with its bounds, so pydantic refuses an out-of-range
value on construction and on decoding, and the refusal names the field (``protocol.codec``). The
bounds hold what any sensor, clock or estimator of this system produces, with a wide margin, and
refuse what none produces; arithmetic on a decoded value therefore cannot overflow (``sim_time_s *
fps`` with a finite ``sim_time_s`` near 1.8e308 would). All bounds are inclusive.

==================  =========================================  =============================================
type                range                                      why
==================  =========================================  =============================================
``TimeS``           0 .. 4.1e9 s                               a clock reading: UNIX seconds up to 2100, or a
                                                               simulated clock counted from a scenario start
``SimTimeS``        0 .. 1e8 s                                 simulated time since the scenario start (3 years)
``DurationS``       0 .. 4.1e9 s                               a span between two clock readings (age, uptime)
``PhaseS``          -1e8 .. 1e8 s                              a time offset within a simulated run
``PositionM``       -1e6 .. 1e6 m                              corridor-frame coordinate: 1,000 km from the
                                                               origin (a flat local frame is meaningless beyond)
``OffsetM``         -2e6 .. 2e6 m                              a signed distance between two positions
``SizeM``           0 .. 1,000 m                               extent of an object or hazard region
``SpeedMps``        0 .. 1,000 m/s                             no road user moves faster; an estimator running
                                                               away (110 m/s seen in real RSU output) passes
``VelocityMps``     -1,000 .. 1,000 m/s                        a velocity component
``AccelMps2``       -1,000 .. 1,000 m/s^2                      100 g: beyond any tyre or crash pulse
``YawRateRps``      -100 .. 100 rad/s                          16 turns per second
``Angle``           -4 pi .. 4 pi rad                          a heading or steering angle (two turns of wrap)
``VarianceM2``      0 .. 1e12 m^2                              a position variance (sigma up to 1,000 km)
``CovarianceM2``    -1e12 .. 1e12 m^2                          a position covariance
``ImageCoordPx``    -1e6 .. 1e6 px                             an image coordinate (boxes may leave the image)
``FlashHz``         0 .. 100 Hz                                a measured flash frequency (camera: <= fps / 2)
``LightBarHz``      0 .. 20 Hz                                 a simulated light bar's flash frequency
``RateHz``          0 .. 1e9 Hz                                a message or loop rate
``LatencyMs``       0 .. 8.64e7 ms                             a processing latency (one day)
``Latitude``        -90 .. 90 deg                              WGS84
``Longitude``       -180 .. 180 deg                            WGS84
``Probability``     0 .. 1                                     a score or confidence
``Lane``            0 .. 15                                    lane index, 0 = rightmost
``Count``           0 .. 2**53                                 ids, sequence numbers, frames, counters (exact
                                                               as a float)
``ColourByte``      0 .. 255                                   one 8-bit colour channel
``ActorLengthM``    (0, 30] m                                  simulated actor footprint and height
``ActorWidthM``     (0, 5] m
``ActorHeightM``    (0, 6] m
==================  =========================================  =============================================

Floats are strict (ints are accepted, strings are not) and finite (NaN and +-inf are refused).
"""

from __future__ import annotations

import math
from typing import Annotated

from pydantic import Field, StrictInt

MAX_TIME_S = 4_102_444_800.0
"""2100-01-01T00:00:00Z in UNIX seconds: the latest clock reading a message may carry."""
MAX_SIM_TIME_S = 1e8
MAX_POSITION_M = 1e6
MAX_OFFSET_M = 2 * MAX_POSITION_M
MAX_SIZE_M = 1000.0
MAX_SPEED_MPS = 1000.0
MAX_ACCEL_MPS2 = 1000.0
MAX_YAW_RATE_RPS = 100.0
MAX_ANGLE_RAD = 4 * math.pi
MAX_VARIANCE_M2 = 1e12
MAX_IMAGE_COORD_PX = 1e6
MAX_FLASH_HZ = 100.0
MAX_LIGHT_BAR_HZ = 20.0
MAX_RATE_HZ = 1e9
MAX_LATENCY_MS = 86_400_000.0
MAX_COUNT = 2**53


def _float(lo: float, hi: float, *, gt: bool = False) -> object:
    """A strict, finite float field in [lo, hi] (or (lo, hi] with ``gt``)."""
    if gt:
        return Field(strict=True, allow_inf_nan=False, gt=lo, le=hi)
    return Field(strict=True, allow_inf_nan=False, ge=lo, le=hi)


Float = Annotated[float, Field(strict=True, allow_inf_nan=False)]
"""A finite float without a physical range (not used by any message field: every field has one)."""
TimeS = Annotated[float, _float(0.0, MAX_TIME_S)]
SimTimeS = Annotated[float, _float(0.0, MAX_SIM_TIME_S)]
DurationS = Annotated[float, _float(0.0, MAX_TIME_S)]
PhaseS = Annotated[float, _float(-MAX_SIM_TIME_S, MAX_SIM_TIME_S)]
PositionM = Annotated[float, _float(-MAX_POSITION_M, MAX_POSITION_M)]
OffsetM = Annotated[float, _float(-MAX_OFFSET_M, MAX_OFFSET_M)]
SizeM = Annotated[float, _float(0.0, MAX_SIZE_M)]
SpeedMps = Annotated[float, _float(0.0, MAX_SPEED_MPS)]
VelocityMps = Annotated[float, _float(-MAX_SPEED_MPS, MAX_SPEED_MPS)]
AccelMps2 = Annotated[float, _float(-MAX_ACCEL_MPS2, MAX_ACCEL_MPS2)]
YawRateRps = Annotated[float, _float(-MAX_YAW_RATE_RPS, MAX_YAW_RATE_RPS)]
Angle = Annotated[float, _float(-MAX_ANGLE_RAD, MAX_ANGLE_RAD)]
VarianceM2 = Annotated[float, _float(0.0, MAX_VARIANCE_M2)]
CovarianceM2 = Annotated[float, _float(-MAX_VARIANCE_M2, MAX_VARIANCE_M2)]
ImageCoordPx = Annotated[float, _float(-MAX_IMAGE_COORD_PX, MAX_IMAGE_COORD_PX)]
FlashHz = Annotated[float, _float(0.0, MAX_FLASH_HZ)]
LightBarHz = Annotated[float, _float(0.0, MAX_LIGHT_BAR_HZ)]
RateHz = Annotated[float, _float(0.0, MAX_RATE_HZ)]
LatencyMs = Annotated[float, _float(0.0, MAX_LATENCY_MS)]
Latitude = Annotated[float, _float(-90.0, 90.0)]
Longitude = Annotated[float, _float(-180.0, 180.0)]
Probability = Annotated[float, _float(0.0, 1.0)]
ActorLengthM = Annotated[float, _float(0.0, 30.0, gt=True)]
ActorWidthM = Annotated[float, _float(0.0, 5.0, gt=True)]
ActorHeightM = Annotated[float, _float(0.0, 6.0, gt=True)]
Lane = Annotated[int, Field(strict=True, ge=0, le=15)]
Count = Annotated[int, Field(strict=True, ge=0, le=MAX_COUNT)]
ColourByte = Annotated[StrictInt, Field(ge=0, le=255)]
