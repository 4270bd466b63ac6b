"""The human-readable sun-sensor ICD, rendered from ``fixtures/devices/sun_sensor.toml``.

    python -m drivers.sun_sensor.icd > docs/sun_sensor_icd.md

A test checks that ``docs/sun_sensor_icd.md`` equals :func:`render` of the fixture.
"""

from __future__ import annotations

from drivers.datagram import render_icd
from drivers.sun_sensor.codec import SunSensorCodec

__all__ = ["render"]


def render(codec: SunSensorCodec | None = None) -> str:
    """The ICD as Markdown."""
    return render_icd(
        codec if codec is not None else SunSensorCodec(),
        title="Sun sensor serial interface (ICD)",
        source="fixtures/devices/sun_sensor.toml",
        generator="drivers.sun_sensor.icd",
        intro="Our own interface for a fine two-axis sun sensor (its content modelled on the Solar MEMS "
        "nanoSSOC-D60 reply: two sun angles, intensity, status) or a coarse sensor of six photodiode heads, in "
        "the stand's datagram family shared with the gyro (see the provenance comment in the TOML). Host = "
        "the flight computer or the stand; device = the sensor or its emulator.",
        exchanges=[
            "A device is either fine (it sends FINE_SAMPLE) or coarse (COARSE_SAMPLE); the host accepts both.",
            "The device sends a sample unasked every output period (default 100 ms) from power-up, and one "
            "at once for each REQUEST_SAMPLE; the sample counter steps by one per sample sent.",
            "Time stamps are the measurement time in the device clock, which counts microseconds from "
            "power-up until SET_TIME sets it; from then on the flag time_synced is set.",
            "FINE_SAMPLE is valid when the Sun is within the field of view and bright enough (not in umbra, "
            "not deep in penumbra); its angles are 0 when it is not valid.",
            "COARSE_SAMPLE: a head current beyond the field's range is sent at the range's end with the "
            "flag saturated, and the sample is then not valid.",
            "Commands are not acknowledged; a command datagram with a bad CRC or a value outside its range "
            "is counted and ignored.",
        ],
    )


if __name__ == "__main__":  # pragma: no cover
    import sys

    sys.stdout.write(render())
